"""Where message definitions come from, without a ROS installation.

In order of precedence for a type a bag uses:

1. the definitions the bag embeds (MCAP schemas in ``ros2msg`` or ``ros2idl``; the
   ``message_definitions`` table of rosbag2 SQLite bags from Iron on; ROS 1 connection
   headers), which rosbags' reader registers on open;
2. the bundled standard types (ROS 2 Humble, or ROS 1 Noetic for ROS 1 bags);
3. the user's ``--msg-path`` folder of ``.msg`` files (``DIR/<pkg>/msg/<Type>.msg``), for the rest;
4. bagport's own bundle of camera video types (:mod:`bagport.bags.bundled`).

rosbag2's ``metadata.yaml`` carries only a hash of each type (``type_description_hash``),
never the definition itself; rosbags checks embedded definitions against it.
A type that no source defines is remembered, and reading its topic fails with
:func:`undefined_type_error`; topics nobody reads are skipped.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Collection, Iterable, Mapping
from typing import Any

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from bagport.bags.bundled import BUNDLED_DEFINITIONS
from bagport.bags.records import ZSTD_FRAME_MAGIC
from bagport.bags.typeload import one_line
from bagport.errors import BagReadError, DecodeError
from bagport.uris import UTF8_FIX

__all__ = [
    "CheckedDeserializer",
    "complete_bag_types",
    "complete_typestore",
    "definition_sources",
    "mismatch_error",
    "parse_msg_definitions",
    "prepare_reading",
    "read_msg_path",
    "undefined_type_error",
]

Typesdict = dict[str, Any]
"""rosbags' parse trees: type name -> (constants, fields)."""


def _type_name(relative: str) -> str | None:
    """``acme_msgs/msg/Gripper.msg`` or ``acme_msgs/Gripper.msg`` -> ``acme_msgs/msg/Gripper``."""
    parts = relative.removesuffix(".msg").split("/")
    if len(parts) >= 3 and parts[-2] == "msg":
        return f"{parts[-3]}/msg/{parts[-1]}"
    if len(parts) >= 2:
        return f"{parts[-2]}/msg/{parts[-1]}"
    return None


def read_msg_path(uri: str) -> dict[str, str]:
    """Every ``.msg`` file under ``uri`` (local folder or fsspec URI): ``{type name: text}``.

    The layout is a ROS workspace's: ``DIR/<package>/msg/<Type>.msg`` (``DIR/<package>/<Type>.msg``
    is accepted too); the folders give the package, as in ROS. Every definition is parsed here (a file
    that is not ROS 2 .msg syntax is one error at the plan, not one per bag, whether a bag uses it or not).
    """
    try:
        fs, root = url_to_fs(uri)
        files = sorted(p for p in fs.find(root) if p.endswith(".msg")) if fs.isdir(root) else []
    except (OSError, ValueError) as err:
        raise BagReadError(f"cannot be listed ({err})", uri=uri, fix="check the --msg-path folder.") from err
    if not files:
        raise BagReadError(
            "holds no .msg files",
            uri=uri,
            fix="point --msg-path at a folder laid out as <package>/msg/<Type>.msg.",
        )
    found: dict[str, str] = {}
    for path in files:
        relative = path[len(root.rstrip("/")) + 1 :]
        file_uri = f"{uri.rstrip('/')}/{relative}"
        name = _type_name(relative)
        if name is None:
            raise BagReadError(
                "is not inside a package folder",
                uri=file_uri,
                fix="move it to <package>/msg/<Type>.msg under the --msg-path folder.",
            )
        found[name] = _msg_text(fs, path, file_uri)
        parse_msg_definitions({name: found[name]}, source=file_uri)
    return found


def _msg_text(fs: AbstractFileSystem, path: str, file_uri: str) -> str:
    """One ``.msg`` file's text; one that cannot be read or is not UTF-8 is a :class:`BagReadError`."""
    try:
        with fs.open(path, "rb") as handle:
            data = handle.read()
    except OSError as err:
        raise BagReadError(
            f"cannot be read ({err.strerror or err})", uri=file_uri, fix="check the file's permissions."
        ) from err
    try:
        return str(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise BagReadError(
            f"is not UTF-8 text (the byte at offset {err.start} is not)", uri=file_uri, fix=UTF8_FIX
        ) from err


def parse_msg_definitions(definitions: Mapping[str, str], source: str = "--msg-path") -> Typesdict:
    """Parse ``{type name: .msg text}`` into rosbags' parse trees."""
    typs: Typesdict = {}
    for name, text in definitions.items():
        try:
            typs.update(_types_from_msg(text, name))
        except (TypesysError, ValueError) as err:
            raise BagReadError(
                f"the definition of {name} cannot be parsed ({one_line(err)})",
                uri=source,
                fix=f"correct the .msg text of {name} (ROS 2 .msg syntax).",
            ) from err
    return typs


@functools.lru_cache(maxsize=256)
def _types_from_msg(text: str, name: str) -> Typesdict:
    """rosbags' parse of one definition, once per process (every bag opened parses bagport's bundled
    types; callers copy the entries out and never change them). Errors are raised each time."""
    return get_types_from_msg(text, name)


def _dependencies(fields: Iterable[tuple[str, Any]]) -> list[str]:
    names = []
    for _, (nodetype, detail) in fields:
        if nodetype == Nodetype.NAME:
            names.append(str(detail))
        elif nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (inner_type, inner_detail), _ = detail
            if inner_type == Nodetype.NAME:
                names.append(str(inner_detail))
    return names


def complete_typestore(
    store: Typestore, msgtypes: Iterable[str], extra: Typesdict, fallback: Typestore
) -> dict[str, str]:
    """Register in ``store`` what ``msgtypes`` need that it lacks, from ``fallback`` (the bundled
    standard types) first, then ``extra``.  Returns ``{msgtype: first type defined nowhere}`` for the
    ones still incomplete."""
    missing: dict[str, str] = {}
    adding: Typesdict = {}
    for msgtype in dict.fromkeys(msgtypes):
        pending, seen, lacking = [msgtype], set(), None
        found: Typesdict = {}
        while pending:
            name = pending.pop()
            if name in seen:
                continue
            seen.add(name)
            definition = store.fielddefs.get(name) or adding.get(name) or fallback.fielddefs.get(name)
            if definition is None:
                definition = extra.get(name)
            if definition is None:
                lacking = name
                break
            if name not in store.fielddefs:
                found[name] = definition
            pending.extend(_dependencies(definition[1]))
        if lacking is not None:
            missing[msgtype] = lacking
        else:
            adding.update(found)
    if adding:
        store.register(adding)
    return missing


def undefined_type_error(uri: str, topic: str, msgtype: str, lacking: str) -> BagReadError:
    detail = "" if lacking == msgtype else f" (it uses {lacking}, which is defined nowhere)"
    return BagReadError(
        f"topic {topic} has type {msgtype}{detail}: the bag does not embed its definition and it is not a "
        "bundled standard type",
        uri=uri,
        topic=topic,
        fix=f"provide it one of three ways: (1) pass --msg-path DIR with DIR/{lacking}.msg "
        "(and the types it uses); (2) record or re-write the bag with definitions embedded (MCAP, "
        "rosbag2 SQLite from Iron on, or ROS 1); (3) remove the topic from the contract if you do not need it.",
    )


def definition_sources(
    msgtypes: Iterable[str], embedded: Collection[str], fallback: Typestore, extra: Typesdict, bundle: str
) -> dict[str, str]:
    """``{msgtype: where its definition came from}``, in the precedence :func:`complete_typestore`
    applies (said in an error when the definition does not match the recorded bytes)."""
    sources: dict[str, str] = {}
    for msgtype in msgtypes:
        if msgtype in embedded:
            sources[msgtype] = "the definition embedded in the bag"
        elif msgtype in fallback.fielddefs:
            sources[msgtype] = f"bagport's bundled {bundle} definition"
        elif msgtype in extra:
            sources[msgtype] = f"--msg-path ({msgtype}.msg)"
    return sources


def mismatch_error(uri: str, msgtype: str, source: str, err: Exception) -> DecodeError:
    """A message whose bytes do not fit the definition it is read with: one paragraph, no dump."""
    reason = one_line(err).rstrip(".") or type(err).__name__
    if source.startswith("--msg-path"):
        fix = (
            f"the {msgtype}.msg under --msg-path is not the definition the robot recorded with: use the "
            "exact .msg of the recording's software version (same fields, same order, same types), "
            "or remove the topic from the contract."
        )
    elif source.startswith("the bag's empty"):
        fix = (
            f"the recorder embedded no definition of {msgtype}: pass it as --msg-path DIR with "
            f"DIR/{msgtype}.msg (and the types it uses), or remove the topic from the contract."
        )
    elif source.startswith("bagport's bundled"):
        fix = (
            "the robot used another version of this standard type (another ROS distribution): re-record "
            "or re-write the bag with its definitions embedded (MCAP, or rosbag2 SQLite from Iron on), "
            "or remove the topic from the contract."
        )
    else:
        fix = (
            "the message's bytes are damaged (copy the bag again from the robot or a backup, or leave this "
            "moment out with the manifest entry's start_s/end_s), or, when every message of the topic "
            "fails, the bag embeds a definition that is not the one its messages were written with: "
            "re-write the bag with the right definition embedded, or remove the topic from the contract."
        )
    return DecodeError(
        f"a message of type {msgtype} does not match {source} (the bytes do not fit: {reason})",
        uri=uri,
        fix=fix,
    )


def complete_bag_types(
    reader: Any, msgtypes: set[str], extra: Typesdict, bundled: Typestore, bundle: str
) -> tuple[dict[str, str], dict[str, str]]:
    """Complete the type store of an open :class:`~bagport.bags.typeload.TolerantAnyReader`:
    ``({msgtype: type defined nowhere}, {msgtype: where its definition came from})``.

    ``--msg-path`` also defines a type whose embedded definition does not parse; a type whose
    embedded definition is an empty placeholder and that no other source defines stays empty
    (reading it then fails with :func:`mismatch_error`, which names the placeholder)."""
    for msgtype in [t for t in reader.unloadable if t in extra]:
        del reader.unloadable[msgtype]
    embedded = set(reader.embedded)  # not the store's types: a bag without definitions reads the bundled ones
    lacking = complete_typestore(reader.typestore, msgtypes, extra, bundled)
    empty: Typesdict = {t: ([], []) for t in reader.placeholders if lacking.get(t) == t}
    if empty:
        reader.typestore.register(empty)
        lacking = complete_typestore(reader.typestore, msgtypes, extra, bundled)
    sources = definition_sources(msgtypes, embedded, bundled, extra, bundle)
    sources.update(dict.fromkeys(empty, "the bag's empty (placeholder) definition"))
    return lacking, sources


class CheckedDeserializer:
    r"""rosbags' ``deserialize`` whose failures (bytes that do not fit the definition) are
    :func:`mismatch_error`\ s naming where the definition came from, never a raw exception."""

    def __init__(self, uri: str, deserialize: Callable[[Any, str], Any], sources: Mapping[str, str]) -> None:
        self._uri = uri
        self._deserialize = deserialize
        self._sources = sources

    def __call__(self, raw: bytes | memoryview, msgtype: str) -> Any:
        try:
            return self._deserialize(raw, msgtype)
        except Exception as err:  # rosbags raises assorted types for bytes that do not fit
            if bytes(raw[:4]) == ZSTD_FRAME_MAGIC:
                raise BagReadError(
                    f"a message of type {msgtype} is zstd-compressed on its own: rosbag2 compressed each message "
                    "(compression_mode: message), which only the bag's metadata.yaml records",
                    uri=self._uri,
                    fix="give the bag's folder (its metadata.yaml beside the data files), not a data file alone.",
                ) from None
            raise mismatch_error(
                self._uri, msgtype, self._sources.get(msgtype, "its definition"), err
            ) from err


def prepare_reading() -> None:
    """Do once what a process's first bag open does first: import rosbags' ROS 2 and ROS 1 type stores and
    parse bagport's bundled definitions (about 80 ms, then cached for the process). The pool's forkserver
    calls it before forking its workers (``flows/worker_preload.py``), so no worker's first episode pays
    it (W3: 164 -> 97 ms for a worker's first episode)."""
    for store in (Stores.ROS2_HUMBLE, Stores.ROS1_NOETIC):
        get_typestore(store)
    parse_msg_definitions(BUNDLED_DEFINITIONS, "bagport's bundled types")
