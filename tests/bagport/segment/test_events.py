"""Episode events from message text and from fields of custom messages."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from bagport.contract.model import EpisodeEvents
from bagport.errors import DecodeError
from bagport.segment import Event, EventKind, event_from_message, parse_event_text


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("SUCCESS", (EventKind.SUCCESS, "")),
        ("  start ", (EventKind.START, "")),
        ("FAIL: gripper slipped", (EventKind.FAIL, "gripper slipped")),
        ("discard operator bumped the table", (EventKind.DISCARD, "operator bumped the table")),
        ('{"event": "FAIL", "note": "dropped the cube"}', (EventKind.FAIL, "dropped the cube")),
        ('{"event": "reset"}', (EventKind.RESET, "")),
        ('{"type": "SUCCESS", "note": null}', (EventKind.SUCCESS, "")),
        ("PAUSE", None),
        ("", None),
        ('{"event": "NOPE"}', None),
        ("{not json", None),
        ("[1, 2]", None),
    ],
    ids=lambda v: repr(v)[:30],
)
def test_event_text(text: str, expected: tuple[EventKind, str] | None) -> None:
    assert parse_event_text(text) == expected


@dataclass
class _Status:
    code: str
    why: str


@dataclass
class _Custom:
    status: _Status


def test_event_from_a_field_of_a_custom_message_with_a_note_field() -> None:
    spec = EpisodeEvents(
        topic="/teleop/status", type="my_msgs/msg/Status", field="status.code", note_field="status.why"
    )
    msg = _Custom(_Status("FAIL", "timeout"))
    assert event_from_message(msg, 7, spec) == Event(7, EventKind.FAIL, "timeout")
    assert event_from_message(_Custom(_Status("IDLE", "")), 8, spec) == "IDLE"


def test_a_wrong_field_path_names_the_topic_and_the_fields() -> None:
    spec = EpisodeEvents(topic="/teleop/status", type="my_msgs/msg/Status", field="status.kind")
    with pytest.raises(DecodeError, match=r"has no field 'kind'.*/teleop/status"):
        event_from_message(_Custom(_Status("FAIL", "")), 1, spec)
