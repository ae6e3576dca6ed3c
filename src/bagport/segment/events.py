"""Episode events from messages: ``SUCCESS``, JSON ``{"event": "FAIL", "note": "..."}``, or message fields."""

from __future__ import annotations

import json
from typing import Any

from bagport.contract.model import EpisodeEvents
from bagport.decode import field_at
from bagport.segment.windows import Event, EventKind

__all__ = ["event_from_message", "parse_event_text"]

_KINDS = {kind.value: kind for kind in EventKind}


def parse_event_text(text: str) -> tuple[EventKind, str] | None:
    """``(kind, note)`` from ``SUCCESS``, ``success: cube placed`` or ``{"event": "SUCCESS", "note": ...}``;
    ``None`` when the text names no known event."""
    text = text.strip()
    if text.startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError:
            return None
        if not isinstance(data, dict):
            return None
        name = str(data.get("event", data.get("type", "")))
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


def event_from_message(msg: Any, t_ns: int, spec: EpisodeEvents) -> Event | str:
    """The event a message carries, or the text it carried when that names no event."""
    value = field_at(msg, spec.field or "data", spec.topic)
    note = str(field_at(msg, spec.note_field, spec.topic)) if spec.note_field else ""
    text = value if isinstance(value, str) else str(value)
    parsed = parse_event_text(text)
    if parsed is None:
        return text
    kind, parsed_note = parsed
    return Event(t_ns, kind, note or parsed_note)
