"""rosbags' AnyReader, minus one habit: failing a whole bag over one type it cannot load.

A real bag often carries topics nobody maps (service events, diagnostics from a vendor
package): when the embedded definition of such a type does not parse, or its RIHS01 hash
does not match what rosbags computes, AnyReader refuses to open the bag at all. This
reader records the type as unloadable instead; reading its topic is an error naming
the topic and the reason, and a contract that does not use it never notices.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError

__all__ = ["TolerantAnyReader", "is_service_event", "one_line"]

_IDL_SEPARATOR = "=" * 80 + "\n"
_SERVICE_EVENT = re.compile(r"(/_service_event$)|(/srv/\w+_Event$)")


def is_service_event(topic: str, msgtype: str) -> bool:
    """A ROS 2 (Iron and later) service introspection topic: requests and responses, not data."""
    return bool(_SERVICE_EVENT.search(topic) or _SERVICE_EVENT.search(msgtype))


def _types_of(connection: Connection) -> dict[str, Any]:
    data = connection.msgdef.data
    if connection.msgdef.format == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(data, connection.msgtype))
    types: dict[str, Any] = {}
    if data.startswith(f"{_IDL_SEPARATOR}IDL: "):
        for block in data.split(_IDL_SEPARATOR)[1:]:
            _, idl = block.split("\n", 1)
            types.update(get_types_from_idl(idl))
        return types
    return dict(get_types_from_idl(data))


def one_line(err: Exception, limit: int = 200) -> str:
    """A type-system error on one line: rosbags' parser dumps the whole definition over many lines
    (``Could not parse:`` / the text / the offset / the rest); keep where it stopped."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    if len(lines) >= 4 and lines[0].startswith("Could not parse") and lines[2].isdigit():
        return f"syntax error at character {lines[2]}, near {lines[3]!r}"
    text = " ".join(lines)
    return text if len(text) <= limit else f"{text[: limit - 3]}..."


class TolerantAnyReader(AnyReader):
    """``AnyReader`` whose ``unloadable`` maps each type it could not load to the reason."""

    def __init__(self, paths: Sequence[Any], *, default_typestore: Any = None) -> None:
        super().__init__(paths, default_typestore=default_typestore)
        self.unloadable: dict[str, str] = {}

    def _open(self) -> None:
        if self.stack is None:
            raise AnyReaderError("AnyReader is not open.")
        for reader in self.readers:
            self.stack.enter_context(reader)
        connections = [c for reader in self.readers for c in reader.connections]
        types: dict[str, Any] = {}
        digests: dict[str, str] = {}
        defined = [c for c in connections if c.msgdef.format != MessageDefinitionFormat.NONE]
        for connection in defined:
            try:
                types.update(_types_of(connection))
            except (TypesysError, ValueError, KeyError, IndexError) as err:
                self.unloadable[connection.msgtype] = (
                    f"its embedded definition does not parse ({one_line(err)})"
                )
                continue
            if connection.digest:
                digests[connection.msgtype] = connection.digest
        if not defined and connections:
            if self.default_typestore is None:
                raise AnyReaderError("Bag contains no type definitions and no default type store was given.")
            types.update(self.default_typestore.fielddefs)
        typestore = get_typestore(Stores.EMPTY)
        typestore.register(types)
        for msgtype, digest in digests.items():
            try:
                have = typestore.hash_rihs01(msgtype) if self.is2 else typestore.generate_msgdef(msgtype)[1]
            except (TypesysError, ValueError, KeyError) as err:
                self.unloadable[msgtype] = f"its definition cannot be hashed ({one_line(err)})"
                continue
            if have != digest:
                self.unloadable[msgtype] = f"its definition hashes to {have}, the bag records {digest}"
        self.connections = connections
        self.typestore = typestore
