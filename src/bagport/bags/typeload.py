"""rosbags' AnyReader, minus one habit: failing a whole bag over one type it cannot load.

A real bag often carries topics nobody maps (service events, diagnostics from a vendor
package): when the embedded definition of such a type does not parse, or its RIHS01 hash
does not match what rosbags computes, AnyReader refuses to open the bag at all. This
reader records the type as unloadable instead; reading its topic is an error naming
the topic and the reason, and a contract that does not use it never notices.

Two more habits of real bags it absorbs:

- a ROS1-style type name inside a rosbag2 bag (an MCAP schema named ``sensor_msgs/Image``):
  rosbags registers the definition as ``sensor_msgs/msg/Image``; digests and unloadable
  types are keyed by that full name too (see :func:`bagport.msgtypes.normalize_msgtype`);
- a ``metadata.yaml`` whose ``offered_qos_profiles`` differ from the ones the storage file
  records for the same topic (rosbag2's own ``talker`` test bags: metadata version 4 wrote
  ``deadline: 0`` where the file has ``2147483647``). rosbags matches a folder's topics to
  the file's by topic, type *and* QoS, so it would read no message at all; QoS does not
  change a message's bytes, so the file's connections take the metadata's QoS;
- an empty embedded definition (a placeholder a recorder writes when it has none) defines
  nothing: the type is completed like one the bag does not embed (bundled, ``--msg-path``);
- ``#include`` lines in a ``ros2idl`` definition (rosbags' IDL parser has no preprocessor):
  they are dropped, and the included types come from the bag's other schemas, the bundled
  types or ``--msg-path`` like any other type a definition uses.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Sequence
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError

from bagport.bags.metadata_yaml import serve_rosbags
from bagport.msgtypes import normalize_msgtype

__all__ = ["TolerantAnyReader", "is_placeholder", "is_service_event", "one_line"]

serve_rosbags()  # rosbags' folder reader parses metadata.yaml once with bagport's reads of it

_IDL_SEPARATOR = "=" * 80 + "\n"
_SERVICE_EVENT = re.compile(r"(/_service_event$)|(/srv/\w+_Event$)")
_INCLUDE = re.compile(r"^[ \t]*#[ \t]*include\b.*$", re.MULTILINE)


def is_service_event(topic: str, msgtype: str) -> bool:
    """A ROS 2 (Iron and later) service introspection topic: requests and responses, not data."""
    return bool(_SERVICE_EVENT.search(topic) or _SERVICE_EVENT.search(msgtype))


def _types_of(msgtype: str, definition_format: MessageDefinitionFormat, data: str) -> dict[str, Any]:
    if definition_format == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(data, msgtype))
    types: dict[str, Any] = {}
    if data.startswith(f"{_IDL_SEPARATOR}IDL: "):
        for block in data.split(_IDL_SEPARATOR)[1:]:
            _, idl = block.split("\n", 1)
            types.update(get_types_from_idl(_INCLUDE.sub("", idl)))
        return types
    return dict(get_types_from_idl(_INCLUDE.sub("", data)))


def one_line(err: BaseException, limit: int = 200) -> str:
    """An exception's text on one line (at most ``limit`` characters), for a message of ours that quotes
    it; rosbags' parser dumps the whole definition over many lines (``Could not parse:`` / the text / the
    offset / the rest): of that, where it stopped."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    if len(lines) >= 4 and lines[0].startswith("Could not parse") and lines[2].isdigit():
        return f"syntax error at character {lines[2]}, near {lines[3]!r}"
    text = " ".join(lines)
    return text if len(text) <= limit else f"{text[: limit - 3]}..."


def is_placeholder(connection: Connection) -> bool:
    """An embedded definition with no text: the recorder had none and wrote an empty one."""
    return connection.msgdef.format != MessageDefinitionFormat.NONE and not connection.msgdef.data.strip()


def _align_qos(reader: Any) -> None:
    """Give a rosbag2 folder's storage connections the QoS its metadata.yaml records for the
    same topic and type, so rosbags' folder reader matches them (see the module docstring)."""
    folder = getattr(reader, "storage", None)
    if not isinstance(folder, DirectoryReader):
        return
    declared = {(c.topic, c.msgtype): c.ext for c in folder.connections}
    for storage in folder.storages:
        storage.connections = [
            c._replace(ext=declared[(c.topic, c.msgtype)])
            if (c.topic, c.msgtype) in declared and c.ext != declared[(c.topic, c.msgtype)]
            else c
            for c in storage.connections
        ]


class TolerantAnyReader(AnyReader):
    """``AnyReader`` whose ``unloadable`` maps each type it could not load to the reason."""

    def __init__(self, paths: Sequence[Any], *, default_typestore: Any = None, store_key: str = "") -> None:
        super().__init__(paths, default_typestore=default_typestore)
        self.unloadable: dict[str, str] = {}
        self.placeholders: set[str] = set()
        """Types whose embedded definition is empty (completed from other sources)."""
        self.embedded: frozenset[str] = frozenset()
        """Types the bag's own definitions define (its connections' and the types they use)."""
        self._store_key = store_key
        """Whatever else the caller registers in the type store (it is shared between bags whose
        definitions and key are equal)."""

    def _open(self) -> None:
        if self.stack is None:
            raise AnyReaderError("AnyReader is not open.")
        for reader in self.readers:
            self.stack.enter_context(reader)
            _align_qos(reader)
        connections = [c for reader in self.readers for c in reader.connections]
        self.placeholders = {normalize_msgtype(c.msgtype) for c in connections if is_placeholder(c)}
        defined = [
            c
            for c in connections
            if c.msgdef.format != MessageDefinitionFormat.NONE and not is_placeholder(c)
        ]
        if not defined and connections:
            if self.default_typestore is None:
                raise AnyReaderError("Bag contains no type definitions and no default type store was given.")
            typestore = get_typestore(Stores.EMPTY)
            typestore.register(self.default_typestore.fielddefs)
            self.embedded = frozenset()  # every type is the default store's, none the bag's
        else:
            found = {(c.msgtype, c.msgdef.format, c.msgdef.data, c.digest) for c in defined}
            key = tuple(sorted(found, key=lambda d: (d[0], str(d[1]), d[2], d[3] or "")))
            typestore, unloadable, self.embedded = _typestore(key, self.is2, self._store_key)
            self.unloadable.update(unloadable)
        self.connections = connections
        self.typestore = typestore

    def warnings(self) -> list[str]:
        """What ``inspect`` should say about the bag's types."""
        return [f"type {t} cannot be loaded: {why}" for t, why in sorted(self.unloadable.items())]


@functools.lru_cache(maxsize=16)
def _typestore(
    definitions: tuple[tuple[str, MessageDefinitionFormat, str, str | None], ...], is2: bool, _store_key: str
) -> tuple[Any, dict[str, str], frozenset[str]]:
    """A type store of the embedded definitions (``(type, format, text, digest)``), the types it
    could not load with the reason, and the types the definitions define (the store, shared, is
    completed from other sources later). Kept per process: bags of one fleet embed the same definitions,
    and the store keeps the deserialisers it generates (a tenth of a one-second episode's time)."""
    types: dict[str, Any] = {}
    digests: dict[str, str] = {}
    unloadable: dict[str, str] = {}
    for msgtype, definition_format, data, digest in definitions:
        try:
            types.update(_types_of(msgtype, definition_format, data))
        except (TypesysError, ValueError, KeyError, IndexError) as err:
            unloadable[normalize_msgtype(msgtype)] = (
                f"its embedded {definition_format.name.lower()} definition does not parse ({one_line(err)})"
            )
            continue
        if digest:
            digests[normalize_msgtype(msgtype)] = digest
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(types)
    for msgtype, digest in digests.items():
        try:
            have = typestore.hash_rihs01(msgtype) if is2 else typestore.generate_msgdef(msgtype)[1]
        except KeyError:
            continue  # it uses a type defined elsewhere (an #include): completed, then read, later
        except (TypesysError, ValueError) as err:
            unloadable[msgtype] = f"its definition cannot be hashed ({one_line(err)})"
            continue
        if have != digest:
            unloadable[msgtype] = f"its definition hashes to {have}, the bag records {digest}"
    return typestore, unloadable, frozenset(types)
