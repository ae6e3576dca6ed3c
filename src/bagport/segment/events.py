"""Episode events from messages: ``SUCCESS``, JSON ``{"event": "FAIL", "note": "..."}``, or message fields.

The seed's raw-log schema is understood as is: ``{"stamp": ..., "episode_id": ..., "event_type":
"START|SUCCESS|FAIL|DISCARD|RESET", "note": ...}`` as JSON in a ``std_msgs/String``, or the same fields
on a custom message type. An event's time is its own ``stamp`` when it carries one (ISO-8601 text,
integer nanoseconds, float seconds, or a ``builtin_interfaces/Time``), unless the contract says
``time: log`` (the bag's log time); its ``episode_id`` travels with the episode it opens.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from typing import Any

from bagport.contract.model import EpisodeEvents
from bagport.decode import field_at
from bagport.errors import DecodeError
from bagport.segment.windows import Event, EventKind

__all__ = ["EVENT_KEYS", "default_event_field", "event_from_message", "json_keys", "parse_event_text"]

_KINDS = {kind.value: kind for kind in EventKind}
EVENT_KEYS = ("event_type", "event", "type")
"""JSON keys (and custom message fields, first found) naming the event."""
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def _json_object(text: str) -> dict[str, Any] | None:
    if not text.startswith("{"):
        return None
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        return None
    return data if isinstance(data, dict) else None


def json_keys(text: str) -> list[str] | None:
    """The keys of a JSON object message (for an error naming what a message holds), else ``None``."""
    data = _json_object(text.strip())
    return None if data is None else sorted(str(k) for k in data)


def parse_event_text(text: str) -> tuple[EventKind, str] | None:
    """``(kind, note)`` from ``SUCCESS``, ``success: cube placed`` or ``{"event_type": "SUCCESS", "note":
    ...}`` (also ``event`` / ``type``); ``None`` when the text names no known event."""
    text = text.strip()
    if text.startswith("{"):
        data = _json_object(text)
        if data is None:
            return None
        name = next((str(data[k]) for k in EVENT_KEYS if data.get(k) is not None), "")
        note = data.get("note", "")
        kind = _KINDS.get(name.strip().upper())
        return None if kind is None else (kind, "" if note is None else str(note))
    head, _, note = text.partition(":")
    words = head.split(maxsplit=1)
    if not words:
        return None
    kind = _KINDS.get(words[0].upper())
    if kind is None:
        return None
    rest = " ".join(part for part in (words[1] if len(words) > 1 else "", note.strip()) if part)
    return kind, rest


def stamp_ns(value: Any, topic: str) -> int | None:
    """An event's own time in ns: ISO-8601 text (naive = UTC), integer ns (or digits), float seconds,
    or a ROS time (``sec`` / ``nanosec``, ROS 1 ``nsecs``); ``None`` when absent or empty."""
    if value is None or value == "":
        return None
    if hasattr(value, "sec"):
        return int(value.sec) * 1_000_000_000 + int(getattr(value, "nanosec", getattr(value, "nsec", 0)))
    if isinstance(value, bool):
        raise DecodeError(f"event stamp {value!r} is not a time", topic=topic, fix=_STAMP_FIX)
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return round(value * 1_000_000_000)
    text = str(value).strip()
    if text.lstrip("-").isdigit():
        return int(text)
    try:
        moment = datetime.fromisoformat(text)
    except ValueError as err:
        raise DecodeError(
            f"event stamp {text[:40]!r} is neither ISO-8601 nor integer nanoseconds",
            topic=topic,
            fix=_STAMP_FIX,
        ) from err
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return ((moment - _EPOCH) // timedelta(microseconds=1)) * 1000


_STAMP_FIX = "publish the stamp as ISO-8601 or integer ns, or set 'time: log' under episodes.events."


def default_event_field(msg: Any) -> str:
    """The field an event message names its event in when the contract says none."""
    if hasattr(msg, "data"):
        return "data"
    return next((k for k in EVENT_KEYS if hasattr(msg, k)), "data")


def event_from_message(msg: Any, t_ns: int, spec: EpisodeEvents) -> Event | str:
    """The event a message carries (at its own stamp unless ``spec.time`` is ``log``), or the text it
    carried when that names no event."""
    value = field_at(msg, spec.field or default_event_field(msg), spec.topic)
    note_field = spec.note_field or ("note" if not hasattr(msg, "data") and hasattr(msg, "note") else None)
    note = str(field_at(msg, note_field, spec.topic)) if note_field else ""
    text = value if isinstance(value, str) else str(value)
    parsed = parse_event_text(text)
    if parsed is None:
        return text
    kind, parsed_note = parsed
    record = _json_object(text.strip()) or {}
    stamp = record.get("stamp", getattr(msg, "stamp", None))
    episode_id = record.get("episode_id", getattr(msg, "episode_id", None))
    at_ns = stamp_ns(stamp, spec.topic) if spec.time == "stamp" else None
    return Event(
        t_ns if at_ns is None else at_ns,
        kind,
        note or parsed_note,
        "" if episode_id is None else str(episode_id),
    )
