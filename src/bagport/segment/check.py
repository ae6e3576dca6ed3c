"""``bagport contract check --bag`` for the ``episodes`` section: its event and done-signal topics exist
with the declared type, and their field paths resolve on the first message."""

from __future__ import annotations

from typing import Any

from bagport.bags import BagReader
from bagport.contract import ContractPlan, normalize_msgtype
from bagport.contract.model import DoneSignal, EpisodeEvents
from bagport.decode import field_at
from bagport.errors import ContractError, DecodeError
from bagport.segment.events import default_event_field, event_from_message, json_keys
from bagport.segment.windows import Event

__all__ = ["check_episode_topics"]


def check_episode_topics(reader: BagReader, plan: ContractPlan) -> None:
    """Raise a :class:`ContractError` at the contract's line when the bag does not fit ``episodes``."""
    options = plan.contract.episodes
    if options is None:
        return
    specs: dict[str, EpisodeEvents | DoneSignal] = {}
    if options.events is not None:
        specs["events"] = options.events
    if options.done_signal is not None:
        specs["done_signal"] = options.done_signal
    for section, spec in specs.items():
        _check_topic(reader, plan, section, spec)
    first = _first_messages(reader, {spec.topic for spec in specs.values()})
    for section, spec in specs.items():
        first_msg = first[spec.topic]
        default = default_event_field(first_msg) if isinstance(spec, EpisodeEvents) else "data"
        paths = {"field": spec.field or default}
        if isinstance(spec, EpisodeEvents) and spec.note_field:
            paths["note_field"] = spec.note_field
        for key, path in paths.items():
            try:
                value = field_at(first_msg, path, spec.topic)
            except DecodeError as err:
                raise _error(
                    plan, section, key, f"{err.what} (first message on {spec.topic})", err.fix
                ) from err
            if isinstance(spec, DoneSignal):
                _check_number(plan, spec, value, path)
    if options.events is not None:
        _check_names_events(reader, plan, options.events)


def _check_names_events(reader: BagReader, plan: ContractPlan, spec: EpisodeEvents) -> None:
    """At least one message of the event topic names an event (else convert would make one episode of
    the whole bag): the error says what the messages hold instead (their JSON keys, or the text)."""
    texts: list[str] = []
    for message in reader.messages((spec.topic,)):
        try:
            found = event_from_message(message.msg(), message.log_time_ns, spec)
        except DecodeError as err:
            raise _error(plan, "events", "field", f"{err.what} (message on {spec.topic})", err.fix) from err
        if isinstance(found, Event):
            return
        texts.append(found)
    if not texts:
        return
    keys = json_keys(texts[0])
    held = f"JSON with keys {keys}" if keys is not None else f"text such as {texts[0][:60]!r}"
    raise _error(
        plan,
        "events",
        "field" if spec.field else "topic",
        f"none of the {len(texts)} message(s) on {spec.topic} in bag {reader.info.uri} names an event "
        f"(START, SUCCESS, FAIL, DISCARD, RESET); they hold {held}",
        "publish the event name as the text or under the JSON key 'event_type' (or 'event' / 'type'), "
        "or set 'field:' under episodes.events to the field that holds it.",
    )


def _check_topic(
    reader: BagReader, plan: ContractPlan, section: str, spec: EpisodeEvents | DoneSignal
) -> None:
    info = reader.info
    found = info.topic(spec.topic)
    if found is None or found.count == 0:
        listing = ", ".join(f"{t.name} ({t.msgtype})" for t in info.topics) or "none"
        what = "is not in" if found is None else "has no messages in"
        raise _error(
            plan,
            section,
            "topic",
            f"episodes.{section} topic {spec.topic} {what} bag {info.uri}; the bag has: {listing}",
            "fix the topic name (convert does not split a bag by a topic the bag lacks; check the contract "
            "against a bag that records it).",
        )
    if normalize_msgtype(found.msgtype) != spec.type:
        raise _error(
            plan,
            section,
            "type",
            f"episodes.{section} topic {spec.topic} in bag {info.uri} has type {found.msgtype}, the contract "
            f"says {spec.type}",
            f"set 'type: {found.msgtype}' under episodes.{section} (and 'field:' to the value's dot path).",
        )


def _check_number(plan: ContractPlan, spec: DoneSignal, value: Any, path: str) -> None:
    try:
        float(value)
    except (TypeError, ValueError) as err:
        raise _error(
            plan,
            "done_signal",
            "field",
            f"episodes.done_signal field {path!r} of the first message on {spec.topic} is "
            f"{type(value).__name__} {str(value)[:40]!r}, not a number or bool",
            "point 'field:' at a bool or number (the done signal ends an episode when it turns true).",
        ) from err


def _first_messages(reader: BagReader, topics: set[str]) -> dict[str, Any]:
    first: dict[str, Any] = {}
    for message in reader.messages(tuple(sorted(topics))):
        if message.topic not in first:
            first[message.topic] = message.msg()
        if len(first) == len(topics):
            break
    return first


def _error(plan: ContractPlan, section: str, key: str, what: str, fix: str) -> ContractError:
    lines = plan.episode_lines
    return ContractError(
        what,
        file=plan.source_name,
        line=lines.get(f"{section}.{key}", lines.get(f"{section}.topic")),
        field=f"episodes.{section}.{key}",
        fix=fix,
    )
