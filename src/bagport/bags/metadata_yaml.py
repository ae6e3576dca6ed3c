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
"""

from __future__ import annotations

import copy
import functools
from typing import Any

import rosbags.rosbag2.reader
import yaml
from ruamel.yaml.error import YAMLError

from bagport.yamlsource import load_plain

__all__ = ["RosbagsMetadataYAML", "parse_metadata", "serve_rosbags"]


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
