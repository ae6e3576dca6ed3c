"""A rosbag2 folder's ``metadata.yaml``, parsed once per bag open instead of four times.

Opening a folder reads its ``metadata.yaml`` in four places: the storage's detection, the layout's
check of the files it lists, the recording's custom data, and rosbags' own folder reader. Each parsed the
text again, rosbags with ruamel's YAML (a new parser object each time, whose construction globs for
plug-ins): 2.6 ms a parse against libyaml's 0.8 ms for a 1.7 KB file, about 4 ms of a small
episode's 125 ms on one core. :func:`parse_metadata` keeps the last few texts' parses (libyaml, as
:func:`bagport.yamlsource.load_plain`) and hands each caller its own copy; rosbags' reader gets it through
:class:`RosbagsMetadataYAML`, which stands in for ruamel's ``YAML`` in ``rosbags.rosbag2.reader`` only
(:func:`serve_rosbags`, called where bagport wraps rosbags' readers, :mod:`bagport.bags.typeload`).

rosbags parsed metadata.yaml as YAML 1.2 (ruamel) and bagport as YAML 1.1 (libyaml); the two read
rosbag2's metadata alike (its keys, names, types, counts and QoS are strings, integers and booleans
that both spell the same way), and bagport's own reads came first and already decided what a
recording's custom data says. A text libyaml cannot parse raises ruamel's ``YAMLError`` inside rosbags,
which reports it as before (bagport's earlier reads of the same text report it first).

bagport's three reads go through :func:`read_metadata`, so a file that is not UTF-8 text, not YAML or not
of the types rosbag2 writes gets the same message whichever of them meets it first.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

import rosbags.rosbag2.reader
import yaml
from ruamel.yaml.error import YAMLError

from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError
from bagport.yamlsource import load_plain

__all__ = ["RosbagsMetadataYAML", "parse_metadata", "read_metadata", "serve_rosbags"]

_FIX = "repair metadata.yaml (`ros2 bag reindex`) or delete it to read the data files present."


@functools.lru_cache(maxsize=8)
def _parsed(text: str) -> Any:
    return load_plain(text)


def parse_metadata(text: str) -> Any:
    """``text`` (a ``metadata.yaml``) parsed, as :func:`bagport.yamlsource.load_plain` parses it: the
    same parse for the same text while it is among the last few, each caller getting a copy of its own."""
    return copy.deepcopy(_parsed(text))


class RosbagsMetadataYAML:
    """What ``rosbags.rosbag2.reader`` calls as ``YAML(typ='safe').load(text)``: :func:`parse_metadata`."""

    def __init__(self, *, typ: str = "safe", **_options: Any) -> None:
        self.typ = typ

    def load(self, text: str) -> Any:
        try:
            return parse_metadata(text)
        except yaml.YAMLError as err:
            raise YAMLError(str(err)) from err


def serve_rosbags() -> None:
    """Make rosbags' folder reader parse ``metadata.yaml`` through :class:`RosbagsMetadataYAML`."""
    rosbags.rosbag2.reader.YAML = RosbagsMetadataYAML  # type: ignore[attr-defined,assignment]


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _type_problem(info: Any) -> str | None:
    """What in a parsed ``rosbag2_bagfile_information`` does not have the type rosbag2 writes (a list of file
    names, whole numbers for counts and times), or ``None``: an edited or damaged file, said before a reader
    fails on it with a bare ``TypeError``."""
    if not isinstance(info, dict):
        return f"rosbag2_bagfile_information is {_kind(info)}, not a mapping"
    files = info.get("relative_file_paths")
    if files is not None and not (isinstance(files, list) and all(isinstance(f, str) for f in files)):
        return f"relative_file_paths is {files!r}, not a list of file names"
    if "message_count" in info and not _whole(info["message_count"]):
        return f"message_count is {info['message_count']!r}, not a whole number"
    for key, field in (("starting_time", "nanoseconds_since_epoch"), ("duration", "nanoseconds")):
        value = info.get(key)
        if value is not None and not (isinstance(value, dict) and _whole(value.get(field))):
            return f"{key} is {value!r}, not {{{field}: <a whole number>}}"
    topics = info.get("topics_with_message_count") or []
    if not isinstance(topics, list):
        return f"topics_with_message_count is {topics!r}, not a list"
    for n, topic in enumerate(topics):
        if not (isinstance(topic, dict) and isinstance(topic.get("topic_metadata"), dict)):
            return f"topics_with_message_count[{n}] is {topic!r}, not {{topic_metadata: ..., message_count: ...}}"
        if not _whole(topic.get("message_count")):
            return f"topics_with_message_count[{n}].message_count is {topic.get('message_count')!r}, not a whole number"
    return None


def _kind(value: Any) -> str:
    """What a parsed YAML value is, in words ("a list", "a number")."""
    kinds = {bool: "true or false", list: "a list", str: "a string", int: "a number", float: "a number"}
    return next((text for kind, text in kinds.items() if isinstance(value, kind)), type(value).__name__)


def read_metadata(folder: Path | RemotePath, uri: str) -> dict[str, Any] | None:
    """The ``rosbag2_bagfile_information`` of ``folder``'s ``metadata.yaml`` (``{}`` when it has none), or
    ``None`` when the folder has no ``metadata.yaml``. A file that is not UTF-8 text, cannot be read or parsed,
    or has values of other types than rosbag2 writes is a :class:`BagReadError` with one fix."""
    metadata = folder / "metadata.yaml"
    if not metadata.is_file():
        return None
    try:
        document = parse_metadata(metadata.read_text()) or {}
    except UnicodeDecodeError as err:
        raise BagReadError(
            f"metadata.yaml is not text (a byte at offset {err.start} is not UTF-8)", uri=uri, fix=_FIX
        ) from err
    except (yaml.YAMLError, OSError, AttributeError, TypeError, ValueError) as err:
        raise BagReadError(f"metadata.yaml is unreadable ({err})", uri=uri, fix=_FIX) from err
    if not isinstance(document, dict):
        what = f"holds {_kind(document)}, not a mapping with rosbag2_bagfile_information"
        raise BagReadError(f"metadata.yaml is damaged or edited: it {what}", uri=uri, fix=_FIX)
    info = document.get("rosbag2_bagfile_information") or {}
    problem = _type_problem(info)
    if problem is not None:
        raise BagReadError(f"metadata.yaml is damaged or edited: {problem}", uri=uri, fix=_FIX)
    return dict(info)
