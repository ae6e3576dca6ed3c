"""``sensor_msgs/msg/JointState`` read straight from its little-endian CDR bytes.

A robot's joint states are its busiest topic (hundreds of messages a second), and rosbags' generic
deserialiser decodes every joint name of every message: about 25 us for 32 joints, most of a small
episode's vector decoding. The names rarely change within a bag, so :class:`JointStateCdr` decodes them
only when their bytes differ from each of the last name lists it saw, and reads the three arrays as
numpy views: about 8 us.

It reads exactly what rosbags reads (its ``deserialize_cdr``: the same alignment, string and sequence
checks and size check), for the built-in JointState extractor only, and only once the first message
gave the same values both ways (:func:`joint_state_reader`). Bytes it cannot read whole give ``None``:
the caller then deserialises them with rosbags, whose error names what is wrong with them.

The same name lookup tells which messages of a topic publishers with different joints share are a
stream's samples (``bagport.episode.samples``), and :func:`joint_lists` what joint lists a topic has.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bagport.bags import BagMessage, BagReader
from bagport.decode.custom import registered_decoder
from bagport.decode.paths import VectorExtractor
from bagport.decode.vector import ExtractorSource
from bagport.errors import DecodeError
from bagport.msgtypes import RosType

__all__ = ["JointStateArrays", "JointStateCdr", "joint_lists", "joint_state_reader"]

_U32 = struct.Struct("<I")
_CDR_LE = b"\x00\x01"
_ENCAPSULATION_BYTES = 4
_STAMP_BYTES = 8
"""header.stamp: int32 sec, uint32 nanosec; the frame_id follows."""
_MAX_SEQUENCE = 2**31
"""Longer sequences than rosbags accepts (its default ``max_sequence_length``) are left to rosbags."""
_KNOWN_NAME_LISTS = 8
"""Distinct name lists remembered per topic (one per publisher, usually)."""


@dataclass(frozen=True, slots=True)
class JointStateArrays:
    """The fields of a JointState the built-in extractor reads (``bagport.decode.joints``)."""

    name: tuple[str, ...]
    position: npt.NDArray[np.float64]
    velocity: npt.NDArray[np.float64]
    effort: npt.NDArray[np.float64]


def _aligned(pos: int, alignment: int) -> int:
    return (pos + alignment - 1) & -alignment


class JointStateCdr:
    """Reads one topic's JointState messages; remembers the last name lists and their bytes."""

    def __init__(self) -> None:
        self._known: list[tuple[bytes, tuple[str, ...]]] = []
        """The latest distinct name lists, newest first, each with the bytes from the header's frame_id to
        its last name (two publishers on one topic alternate between theirs): a message starting with
        those bytes after its stamp has those names."""

    def read(self, raw: bytes | memoryview) -> JointStateArrays | None:
        """The message's names and arrays, or ``None`` when the bytes are not a whole little-endian
        CDR JointState (rosbags then says why)."""
        body = _body(raw)
        if body is None:
            return None
        try:
            return self._read(body)
        except (struct.error, ValueError, UnicodeDecodeError):
            return None

    def names(self, raw: bytes | memoryview) -> tuple[str, ...] | None:
        """Only the message's joint names (``None`` as for :meth:`read`): whether a message is a sample
        of a stream that selects joints, asked of every message of the topic, so known names are found
        without copying the message."""
        data = raw if isinstance(raw, bytes) else bytes(raw)
        if data.startswith(_CDR_LE):
            for region, names in self._known:
                if data.startswith(region, _ENCAPSULATION_BYTES + _STAMP_BYTES):
                    return names
        body = _body(data)
        if body is None:
            return None
        try:
            found = self._parse_names(body)  # none of the known lists: read and remember this one
        except (struct.error, ValueError, UnicodeDecodeError):
            return None
        return None if found is None else found[0]

    def names_of(self, message: BagMessage) -> tuple[str, ...]:
        """The joint names of a JointState message: from its bytes, else (ROS 1, big-endian, bytes rosbags
        must judge) from the deserialised message."""
        raw = message.cdr
        names = None if raw is None else self.names(raw)
        return tuple(message.msg().name) if names is None else names

    def _names(self, body: bytes) -> tuple[tuple[str, ...], int] | None:
        """The names and the offset after them."""
        for region, names in self._known:
            if body.startswith(region, _STAMP_BYTES):
                return names, _STAMP_BYTES + len(region)
        return self._parse_names(body)

    def _parse_names(self, body: bytes) -> tuple[tuple[str, ...], int] | None:
        pos = _STAMP_BYTES
        frame_id_bytes = _U32.unpack_from(body, pos)[0]
        if not _whole_string(body, pos, frame_id_bytes):
            return None
        pos = _aligned(pos + 4 + frame_id_bytes, 4)
        count = _U32.unpack_from(body, pos)[0]
        parsed = self._names_at(body, pos + 4, count)
        if parsed is None:
            return None
        self._known = [(body[_STAMP_BYTES : parsed[0]], parsed[1]), *self._known[: _KNOWN_NAME_LISTS - 1]]
        return parsed[1], parsed[0]

    def _read(self, body: bytes) -> JointStateArrays | None:
        found = self._names(body)
        if found is None:
            return None
        names, pos = found
        arrays = []
        for _ in range(3):  # position, velocity, effort
            pos = _aligned(pos, 4)
            size = _U32.unpack_from(body, pos)[0]
            pos += 4
            if size > _MAX_SEQUENCE or pos + size * 8 > len(body):
                return None
            if size:
                pos = _aligned(pos, 8)
            arrays.append(np.frombuffer(body, dtype="<f8", count=size, offset=pos))
            pos += size * 8
        if pos + 3 < len(body):  # rosbags' size check: more than padding left over
            return None
        return JointStateArrays(names, *arrays)

    @staticmethod
    def _names_at(body: bytes, pos: int, count: int) -> tuple[int, tuple[str, ...]] | None:
        if count > _MAX_SEQUENCE or pos + count * 5 > len(body):
            return None
        names = []
        for _ in range(count):
            pos = _aligned(pos, 4)
            length = _U32.unpack_from(body, pos)[0]
            if not _whole_string(body, pos, length):
                return None
            names.append(body[pos + 4 : pos + 3 + length].decode())
            pos += 4 + length
        return pos, tuple(names)


def joint_lists(reader: BagReader, topics: Sequence[str], limit: int) -> dict[str, list[tuple[str, ...]]]:
    """The distinct joint name lists of each JointState topic in ``topics``, in the order they first appear
    (two when an arm's and a gripper's driver share /joint_states), from its first ``limit`` messages."""
    found: dict[str, dict[tuple[str, ...], None]] = {topic: {} for topic in topics}
    if not found:
        return {}
    readers = {topic: JointStateCdr() for topic in found}
    read = dict.fromkeys(found, 0)
    for message in reader.messages(tuple(found)):
        found[message.topic][readers[message.topic].names_of(message)] = None
        read[message.topic] += 1
        if all(n >= limit for n in read.values()):
            break
    return {topic: list(lists) for topic, lists in found.items()}


def _body(raw: bytes | memoryview) -> bytes | None:
    """The CDR body after the encapsulation header, when little-endian."""
    data = bytes(raw)  # one copy of a few hundred bytes: bytes compare and slice faster than views
    if not data.startswith(_CDR_LE) or len(data) < _ENCAPSULATION_BYTES:
        return None
    return data[_ENCAPSULATION_BYTES:]


def _whole_string(body: bytes, pos: int, length: int) -> bool:
    """rosbags' ``check_string``: a CDR string holds at least its terminator, which is there."""
    end = pos + 4 + length
    return length >= 1 and end <= len(body) and body[end - 1] == 0


def joint_state_reader(
    src: ExtractorSource, extractor: VectorExtractor, first_raw: bytes | memoryview | None, first_msg: object
) -> JointStateCdr | None:
    """A reader for ``src``'s further messages when it is a JointState read by the built-in extractor
    and its first message (``first_raw``, deserialised as ``first_msg``) gives the same values read
    either way; else ``None`` (a custom decoder, a ROS 1 or big-endian bag, a type the bag defines
    differently)."""
    if src.msgtype != RosType.JOINT_STATE or src.decoder is not None or first_raw is None:
        return None
    if registered_decoder(src.msgtype) is not None:
        return None
    reader = JointStateCdr()
    arrays = reader.read(first_raw)
    if arrays is None:
        return None
    try:
        same = extractor(arrays).tobytes() == extractor(first_msg).tobytes()
    except (AttributeError, TypeError, IndexError, DecodeError):
        return None
    return reader if same else None
