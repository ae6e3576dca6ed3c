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

from collections.abc import Iterable, Mapping
from typing import Any

from fsspec.core import url_to_fs
from rosbags.interfaces import Nodetype
from rosbags.typesys import TypesysError, get_types_from_msg
from rosbags.typesys.store import Typestore

from bagport.errors import BagReadError

__all__ = ["complete_typestore", "parse_msg_definitions", "read_msg_path", "undefined_type_error"]

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
    is accepted too); the folders give the package, as in ROS.
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
        name = _type_name(relative)
        if name is None:
            raise BagReadError(
                "is not inside a package folder",
                uri=f"{uri.rstrip('/')}/{relative}",
                fix="move it to <package>/msg/<Type>.msg under the --msg-path folder.",
            )
        with fs.open(path, "rb") as handle:
            found[name] = handle.read().decode("utf-8")
    return found


def parse_msg_definitions(definitions: Mapping[str, str], source: str = "--msg-path") -> Typesdict:
    """Parse ``{type name: .msg text}`` into rosbags' parse trees."""
    typs: Typesdict = {}
    for name, text in definitions.items():
        try:
            typs.update(get_types_from_msg(text, name))
        except (TypesysError, ValueError) as err:
            raise BagReadError(
                f"the definition of {name} cannot be parsed ({' '.join(str(err).split())})",
                uri=source,
                fix=f"fix the file {name}.msg (ROS 2 .msg syntax).",
            ) from err
    return typs


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
