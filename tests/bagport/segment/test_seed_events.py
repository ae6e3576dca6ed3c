"""The seed's episode-event schema: ``{stamp, episode_id, event_type, note}`` as JSON in a String, or as a
custom message type. Events take their own stamps' times, ``episode_id`` reaches metadata and provenance."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bagport.contract import parse_contract
from bagport.errors import ContractError, DecodeError
from bagport.feature_table import describe_features
from bagport.segment import segment_request
from tests.bagport.decode.bagwriter import Stream, write_bag
from tests.helpers import convert_in_process, episode_request

TS = get_typestore(Stores.ROS2_HUMBLE)
TS.register(
    get_types_from_msg(
        "builtin_interfaces/Time stamp\nstring episode_id\nstring event_type\nstring note\n",
        "humanoid_msgs/msg/TaskEvent",
    )
)
T = TS.types
S = 1_000_000_000
START_NS = 1_700_000_000 * S
FPS = 10
EVENT_TOPIC = "/humanoid/task/event"
LATE_NS = 250_000_000
"""Events are logged a quarter second after their own stamp (published late)."""
SCENARIO = [  # (stamp s, event_type, episode_id, note)
    (1.0, "START", "ep-1", ""),
    (4.0, "SUCCESS", "ep-1", "placed"),
    (5.0, "RESET", "", ""),
    (6.0, "START", "ep-2", ""),
    (9.0, "FAIL", "ep-2", "dropped the cup"),
]


def _iso(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns // S, tz=UTC).isoformat().replace("+00:00", ".000000Z")


def _joints() -> Stream:
    """Position = seconds since the bag's start, every 0.1 s for 10 s: a frame's value tells its time."""
    msgs = []
    for k in range(101):
        t_ns = START_NS + k * S // FPS
        msgs.append(
            (
                t_ns,
                T["sensor_msgs/msg/JointState"](
                    header=T["std_msgs/msg/Header"](
                        stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // S, nanosec=t_ns % S), frame_id=""
                    ),
                    name=["lift"],
                    position=np.array([k / FPS]),
                    velocity=np.array([], dtype=np.float64),
                    effort=np.array([], dtype=np.float64),
                ),
            )
        )
    return ("/joint_states", "sensor_msgs/msg/JointState", msgs)


def _json_events(keys: tuple[str, str] = ("event_type", "stamp")) -> Stream:
    event_key, stamp_key = keys
    msgs = []
    for k, (at_s, kind, episode, note) in enumerate(SCENARIO):
        stamp_ns = START_NS + round(at_s * S)
        stamp: Any = _iso(stamp_ns) if k % 2 == 0 else stamp_ns  # both forms the seed allows
        record = {stamp_key: stamp, "episode_id": episode, event_key: kind, "note": note}
        msgs.append((stamp_ns + LATE_NS, T["std_msgs/msg/String"](data=json.dumps(record))))
    return (EVENT_TOPIC, "std_msgs/msg/String", msgs)


def _custom_events() -> Stream:
    msgs = []
    for at_s, kind, episode, note in SCENARIO:
        stamp_ns = START_NS + round(at_s * S)
        stamp = T["builtin_interfaces/msg/Time"](sec=stamp_ns // S, nanosec=stamp_ns % S)
        event = T["humanoid_msgs/msg/TaskEvent"](stamp=stamp, episode_id=episode, event_type=kind, note=note)
        msgs.append((stamp_ns + LATE_NS, event))
    return (EVENT_TOPIC, "humanoid_msgs/msg/TaskEvent", msgs)


def _contract(event_type: str = "std_msgs/msg/String", time: str = "stamp") -> str:
    return (
        f"robot_type: humanoid\nfps: {FPS}\ndefault_task: pour\n"
        "observations:\n"
        "  - {key: observation.state, topic: /joint_states, type: sensor_msgs/msg/JointState,"
        " align: {strategy: hold, stamp: receive}}\n"
        f"episodes:\n  events: {{topic: {EVENT_TOPIC}, type: {event_type}, time: {time}}}\n"
    )


def _spans_s(bag: Path, contract: str, tmp_path: Path) -> list[tuple[float, float, str | None, str]]:
    found = segment_request(episode_request(bag, tmp_path / "staging", contract))
    return [
        (
            ((r.window.start_ns or 0) - START_NS) / S,
            ((r.window.end_ns or 0) - START_NS) / S,
            r.label,
            str(r.metadata.get("episode_id", "")),
        )
        for r in found.requests
    ]


def test_seed_scenario_converts_to_one_kept_and_one_failed_episode(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = write_bag(tmp_path / "pilot", "mcap", TS, [_joints(), _json_events()])
    assert _spans_s(bag, _contract(), tmp_path) == [
        (1.0, 4.0, "success", "ep-1"),
        (6.0, 9.0, "failed", "ep-2"),
    ]
    out = convert_in_process(str(bag), _contract(), tmp_path, repo_id="test/seed")
    dataset = LeRobotDataset("test/seed", root=out)
    assert dataset.meta.total_episodes == 1
    values = np.array(
        [float(dataset[k]["observation.state"].reshape(-1)[0]) for k in range(dataset.meta.total_frames)]
    )
    # frames at the stamps' times (1.0 .. 4.0 s), not at the events' log times (1.25 .. 4.25 s)
    np.testing.assert_allclose(values, np.arange(10, 41) / FPS, atol=1e-6)
    record = json.loads((out / "meta" / "provenance" / "run.json").read_text())
    (kept,) = record["episodes"]
    assert (kept["label"], kept["metadata"]["episode_id"]) == ("success", "ep-1")
    (excluded,) = record["excluded"]
    assert (excluded["label"], excluded["note"], excluded["metadata"]["episode_id"]) == (
        "failed",
        "dropped the cup",
        "ep-2",
    )


def test_log_time_option_and_custom_event_message_type(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "pilot", "mcap", TS, [_joints(), _json_events()])
    assert _spans_s(bag, _contract(time="log"), tmp_path) == [
        (1.25, 4.25, "success", "ep-1"),
        (6.25, 9.25, "failed", "ep-2"),
    ]
    custom = write_bag(tmp_path / "production", "mcap", TS, [_joints(), _custom_events()])
    contract = _contract("humanoid_msgs/msg/TaskEvent")
    describe_features(parse_contract(contract, "c.yaml"), str(custom))  # contract check --bag passes
    assert _spans_s(custom, contract, tmp_path) == [
        (1.0, 4.0, "success", "ep-1"),
        (6.0, 9.0, "failed", "ep-2"),
    ]


def test_event_topic_naming_no_event_fails_check_and_convert(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "pilot", "mcap", TS, [_joints(), _json_events(("kind", "stamp"))])
    with pytest.raises(ContractError) as caught:
        describe_features(parse_contract(_contract(), "c.yaml"), str(bag))
    assert str(caught.value) == (
        f"c.yaml:7 (episodes.events.topic): none of the 5 message(s) on {EVENT_TOPIC} in bag {bag} names an "
        "event (START, SUCCESS, FAIL, DISCARD, RESET); they hold JSON with keys ['episode_id', 'kind', 'note', "
        "'stamp'] Fix: publish the event name as the text or under the JSON key 'event_type' (or 'event' / "
        "'type'), or set 'field:' under episodes.events to the field that holds it."
    )
    with pytest.raises(DecodeError, match="none of the 5 message"):
        segment_request(episode_request(bag, tmp_path / "staging", _contract()))


def test_an_unreadable_or_foreign_clock_stamp_says_use_log_time(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "pilot", "mcap", TS, [_joints(), _json_events(("event_type", "stamp"))])
    events = (
        EVENT_TOPIC,
        "std_msgs/msg/String",
        [(START_NS, T["std_msgs/msg/String"](data='{"event_type": "START", "stamp": "noon"}'))],
    )
    bad = write_bag(tmp_path / "bad", "mcap", TS, [_joints(), events])
    with pytest.raises(
        DecodeError, match=r"event stamp 'noon' is neither ISO-8601 nor integer nanoseconds.*time: log"
    ):
        segment_request(episode_request(bad, tmp_path / "staging", _contract()))
    sim = (
        EVENT_TOPIC,
        "std_msgs/msg/String",
        [(START_NS, T["std_msgs/msg/String"](data='{"event_type": "START", "stamp": 5}'))],
    )
    foreign = write_bag(tmp_path / "sim", "mcap", TS, [_joints(), sim])
    with pytest.raises(DecodeError, match=r"outside the bag: its stamp is not on the bag's clock.*time: log"):
        segment_request(episode_request(foreign, tmp_path / "staging", _contract()))
    assert _spans_s(bag, _contract(), tmp_path)[0][:2] == (1.0, 4.0)
