"""A message read from a bag: metadata now, payload deserialised only on demand."""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from rosbags.highlevel import AnyReaderError

from bagport.bags.typeload import one_line
from bagport.errors import DecodeError

__all__ = ["BagMessage", "HeaderLayout"]

_LE = struct.Struct("<iI")
_BE = struct.Struct(">iI")
_ROS1 = struct.Struct("<II")
_DAMAGED = (AnyReaderError, struct.error, IndexError, KeyError, ValueError, UnicodeDecodeError)
"""What rosbags' deserialisers raise on bytes that do not hold a message of the type."""


class HeaderLayout:
    """Where ``header.stamp`` sits in the raw bytes of a message whose first field is a Header."""

    CDR = "cdr"
    ROS1 = "ros1"
    ROS1_TIME = "ros1-time"
    """ROS 1 type whose first field is a bare ``time`` (no ``seq`` before it)."""


def stamp_from_raw(raw: bytes | memoryview, layout: str) -> int | None:
    """``header.stamp`` in ns parsed from the serialised bytes, without deserialising."""
    if layout == HeaderLayout.CDR:
        if len(raw) < 12:
            return None
        little = raw[1] == 1
        sec, nanosec = (_LE if little else _BE).unpack_from(raw, 4)
    else:
        offset = 0 if layout == HeaderLayout.ROS1_TIME else 4
        if len(raw) < offset + 8:
            return None
        sec, nanosec = _ROS1.unpack_from(raw, offset)
    return int(sec) * 1_000_000_000 + int(nanosec)


def fields_after_header(
    raw: bytes | memoryview, layout: str, fmt: str, strings: int = 0
) -> tuple[int, ...] | None:
    """The fields right after a leading std_msgs/Header (its stamp and frame_id skipped, then ``strings``
    string fields), unpacked with the struct format ``fmt`` (``"II"``: an Image's height and width), without
    deserialising; ``None`` when the bytes end first or the layout has no such header."""
    if layout not in (HeaderLayout.CDR, HeaderLayout.ROS1):
        return None
    cdr = layout == HeaderLayout.CDR
    order = ("<" if raw[1] == 1 else ">") if cdr else "<"
    try:
        at = 12  # CDR: encapsulation 4 + stamp 8; ROS 1: seq 4 + stamp 8
        for _ in range(strings + 1):  # the frame_id, then the strings
            (length,) = struct.unpack_from(order + "I", raw, at)
            at += 4 + length
            if cdr:
                at += -(at - 4) % 4  # CDR aligns from the end of the encapsulation header
        if at > len(raw):
            return None
        return struct.unpack_from(order + fmt, raw, at)
    except (struct.error, IndexError):
        return None


class BagMessage:
    __slots__ = ("_deserialize", "_layout", "_msg", "_raw", "log_time_ns", "msgtype", "topic", "uri")

    def __init__(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        raw: bytes | memoryview,
        deserialize: Callable[[bytes | memoryview, str], Any],
        header_layout: str | None,
        uri: str | None = None,
    ) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.log_time_ns = log_time_ns
        self._raw = raw
        self._deserialize = deserialize
        self._layout = header_layout
        self._msg: Any = None
        self.uri = uri

    def msg(self) -> Any:
        """The deserialised message (a rosbags dataclass); cached."""
        if self._msg is None:
            try:
                self._msg = self._deserialize(self._raw, self.msgtype)
            except DecodeError as err:
                raise err.located(uri=self.uri or "", topic=self.topic, t_ns=self.log_time_ns) from err
            except _DAMAGED as err:
                raise DecodeError(
                    f"the {len(self._raw)}-byte message does not deserialise as {self.msgtype} "
                    f"({one_line(err)}): its bytes are damaged",
                    uri=self.uri,
                    topic=self.topic,
                    t_ns=self.log_time_ns,
                    fix="copy the bag again from the robot or a backup, or leave this moment out with the "
                    "manifest entry's start_s/end_s.",
                ) from err
        return self._msg

    def fields_after_header(self, fmt: str, strings: int = 0) -> tuple[int, ...] | None:
        """:func:`fields_after_header` of this message's bytes."""
        return None if self._layout is None else fields_after_header(self._raw, self._layout, fmt, strings)

    def header_stamp_ns(self) -> int | None:
        """``header.stamp`` in ns when the type starts with a std_msgs/Header, else ``None``."""
        if self._layout is None:
            return None
        return stamp_from_raw(self._raw, self._layout)

    @property
    def raw_size(self) -> int:
        return len(self._raw)

    @property
    def cdr(self) -> bytes | memoryview | None:
        """The serialised bytes of a ROS 2 message whose type starts with a Header, else ``None``."""
        return self._raw if self._layout == HeaderLayout.CDR else None
