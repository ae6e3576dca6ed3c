"""The contract's time options against ground truth: action offset, clock stream, publish stamps,
slerp of quaternions, and deterministic handling of disordered stamps."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from bagport.columns import vector_column
from bagport.episode import convert_episode
from bagport.errors import AlignmentError, ContractError
from bagport.staging import FRAMES_FILE, PROVENANCE_FILE, QA_FILE, EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, Faults, GroundTruth, Window, write_episode_bag
from tests.helpers import episode_request

NS = 1_000_000_000
Float = npt.NDArray[np.float64]
# linear interpolation error bound between samples h apart: max|q''| h^2 / 8, plus float32 storage
CURVATURE = (2 * np.pi * 0.5) ** 2


def _bound(rate_hz: float) -> float:
    return CURVATURE * (1 / rate_hz) ** 2 / 8 + 1e-6


def _convert(bag: Path, staging: Path, text: str) -> EpisodeSummary:
    return convert_episode(episode_request(bag, staging, text, task="t"))


def _vectors(summary: EpisodeSummary, key: str) -> Float:
    return vector_column(pq.read_table(Path(summary.dir_uri) / FRAMES_FILE), key)


def _ticks(summary: EpisodeSummary, key: str) -> npt.NDArray[np.int64]:
    prov = pq.read_table(Path(summary.dir_uri) / PROVENANCE_FILE).to_pylist()
    return np.array([r["tick_ns"] for r in prov if r["key"] == key], dtype=np.int64)


def _contract(header: str = "", fps: int = 30, action_align: str = "{strategy: interpolate}") -> str:
    return f"""\
robot_type: r
fps: {fps}
{header}
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
    align: {{strategy: interpolate}}
actions:
  - key: action
    publish: {{topic: /cmd, type: sensor_msgs/msg/JointState}}
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
    align: {action_align}
"""


@pytest.fixture(scope="module")
def arm(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, GroundTruth]:
    """100 Hz joints and 50 Hz commands leading the motion by 100 ms (the execution delay)."""
    root = tmp_path_factory.mktemp("arm")
    spec = EpisodeSpec(duration_s=2.0, joint_rate_hz=100, cameras=(), task=None, seed=3, action_lead_s=0.1)
    return root / "ep", write_episode_bag(root / "ep", "mcap", spec)


def test_action_offset_compensates_the_command_to_execution_delay(
    tmp_path: Path, arm: tuple[Path, GroundTruth]
) -> None:
    bag, truth = arm
    plain = _convert(bag, tmp_path / "plain", _contract())
    shifted = _convert(bag, tmp_path / "ms", _contract("action_offset_ms: -100"))
    for summary in (plain, shifted):
        assert (_ticks(summary, "action") == _ticks(summary, "observation.state")).all()
    # without the offset the action leads the state by the 100 ms delay; with it, it matches the state
    ticks = _ticks(plain, "action")
    assert np.abs(_vectors(plain, "action") - truth.joint_position(ticks)).max() > 0.02
    np.testing.assert_allclose(_vectors(plain, "action"), truth.action_position(ticks), atol=_bound(50))
    ticks = _ticks(shifted, "action")
    np.testing.assert_allclose(_vectors(shifted, "action"), truth.joint_position(ticks), atol=_bound(50))
    # the grid starts only once the shifted action stream has data
    assert shifted.first_tick_ns >= int(truth.action_stamps_ns()[0]) + 100_000_000
    report = {r["key"]: r for r in shifted.alignment}
    assert report["action"]["offset_ms"] == -100.0 and report["observation.state"]["offset_ms"] == 0.0
    frames = _convert(bag, tmp_path / "frames", _contract("action_offset_frames: -3"))
    np.testing.assert_array_equal(_vectors(frames, "action"), _vectors(shifted, "action"))


def test_action_offset_in_ms_and_frames_at_once_is_refused(
    tmp_path: Path, arm: tuple[Path, GroundTruth]
) -> None:
    with pytest.raises(ContractError, match="sets both action_offset_ms and action_offset_frames"):
        _convert(arm[0], tmp_path, _contract("action_offset_ms: 10\naction_offset_frames: 1"))


def test_clock_makes_one_frame_per_reference_message(tmp_path: Path, arm: tuple[Path, GroundTruth]) -> None:
    bag, truth = arm
    summary = _convert(
        bag, tmp_path / "st", _contract("clock: action", fps=50, action_align="{strategy: hold}")
    )
    ticks = _ticks(summary, "action")
    commands = truth.action_stamps_ns()
    # every tick is a command's stamp, consecutive: "observation at t -> action at t"
    first = int(np.searchsorted(commands, ticks[0]))
    np.testing.assert_array_equal(ticks, commands[first : first + ticks.size])
    np.testing.assert_allclose(_vectors(summary, "action"), truth.action_position(ticks), atol=1e-6)
    np.testing.assert_allclose(
        _vectors(summary, "observation.state"), truth.joint_position(ticks), atol=_bound(100)
    )
    clock = next(r for r in summary.alignment if r["key"] == "action")["clock"]
    assert clock["rate_hz"] == pytest.approx(50.0) and clock["drift_ms"]["max"] < 0.001
    qa = json.loads((Path(summary.dir_uri) / QA_FILE).read_text())
    drift = next(c for c in qa["checks"] if c["check"] == "time.clock_drift_ms")
    assert drift["verdict"] == "pass"


def test_clock_at_another_rate_than_fps_is_refused(tmp_path: Path, arm: tuple[Path, GroundTruth]) -> None:
    with pytest.raises(AlignmentError, match=r"runs at 50\.00 Hz .* but fps is 30.*Fix: set 'fps: 50'"):
        _convert(arm[0], tmp_path, _contract("clock: action"))
    with pytest.raises(ContractError, match=r"clock 'observation\.image' is not a feature key"):
        _convert(arm[0], tmp_path, _contract("clock: observation.image"))


def test_clock_on_a_camera_with_a_dropout_reports_the_drift(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        duration_s=1.5,
        cameras=(CameraSpec("front", "raw", jitter_ns=2_000_000),),
        faults=Faults(camera_dropout=Window(0.5, 0.3, "front")),
        task=None,
    )
    truth = write_episode_bag(tmp_path / "ep", "mcap", spec)
    text = _contract("clock: observation.images.front").replace(
        "actions:",
        "  - key: observation.images.front\n    topic: /front/image_raw\n    type: sensor_msgs/msg/Image\nactions:",
    )
    summary = _convert(tmp_path / "ep", tmp_path / "st", text)
    ticks = _ticks(summary, "observation.images.front")
    camera = truth.camera_stamps_ns("front")
    assert set(ticks.tolist()) <= set(camera.tolist())  # frames only where the camera published
    clock = next(r for r in summary.alignment if r["key"] == "observation.images.front")["clock"]
    assert 250 < clock["drift_ms"]["max"] < 320  # the 300 ms dropout: later frames come early
    qa = json.loads((Path(summary.dir_uri) / QA_FILE).read_text())
    drift = next(c for c in qa["checks"] if c["check"] == "time.clock_drift_ms")
    assert drift["verdict"] == "warn" and drift["value"] == clock["drift_ms"]["max"]


def test_publish_stamps_are_used_where_the_bag_has_them(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        duration_s=1.0, cameras=(), task=None, publish_lag_ns=700_000, joint_latency_ns=9_000_000
    )
    truth = write_episode_bag(tmp_path / "mcap", "mcap", spec)
    text = _contract().replace(
        "align: {strategy: interpolate}\nactions", "align: {strategy: hold, stamp: publish}\nactions"
    )
    summary = _convert(tmp_path / "mcap", tmp_path / "st", text)
    assert summary.stamp_sources["observation.state@/joint_states"] == "publish"
    prov = [
        r
        for r in pq.read_table(Path(summary.dir_uri) / PROVENANCE_FILE).to_pylist()
        if r["key"] == "observation.state"
    ]
    captured = truth.joint_stamps_ns()
    for row in prov:
        assert row["source_publish_ns"] - row["source_header_ns"] == 700_000
        assert row["source_log_ns"] - row["source_header_ns"] == 9_000_000  # receive time kept
        assert 0 <= row["tick_ns"] - row["source_publish_ns"] < 10_000_000
        assert row["source_header_ns"] in captured
    write_episode_bag(tmp_path / "sqlite", "sqlite3", replace(spec, publish_lag_ns=None))
    with pytest.raises(
        AlignmentError, match=r"records no publish time .*Fix: set 'align: \{stamp: receive\}'"
    ):
        _convert(tmp_path / "sqlite", tmp_path / "st2", text)


def _rotation(axis: Float, angle: Float) -> Float:
    unit = axis / np.linalg.norm(axis)
    half = np.asarray(angle)[..., None] / 2
    out: Float = np.concatenate([unit * np.sin(half), np.cos(half)], axis=-1)
    return out


AXIS = np.array([0.3, -0.5, 0.8])
OMEGA = 3.0  # rad/s


def _write_pose_bag(
    path: Path, rate_hz: float, duration_s: float, header_ns: Callable[[int], int] = lambda t: t
) -> npt.NDArray[np.int64]:
    """``/pose`` rotating at ``OMEGA`` about ``AXIS``; logged 1 ms after capture, header from ``header_ns``."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: Any = store.types
    start = 1_700_000_000 * NS
    stamps = start + (np.arange(int(duration_s * rate_hz) + 1) * NS / rate_hz).astype(np.int64)
    writer = Writer(path, version=9)
    writer.open()
    conn = writer.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=store)
    for stamp in stamps.tolist():
        t = (stamp - start) / NS
        x, y, z, w = _rotation(AXIS, np.array(OMEGA * t)).tolist()
        header = header_ns(stamp)
        msg = types["geometry_msgs/msg/PoseStamped"](
            header=types["std_msgs/msg/Header"](
                stamp=types["builtin_interfaces/msg/Time"](sec=header // NS, nanosec=header % NS),
                frame_id="w",
            ),
            pose=types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=2.0 * t, y=-t, z=0.5),
                orientation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
            ),
        )
        writer.write(conn, stamp + 1_000_000, store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))
    writer.close()
    return stamps


def test_interpolate_slerps_quaternions_of_default_pose_fields(tmp_path: Path) -> None:
    stamps = _write_pose_bag(tmp_path / "pose", rate_hz=10.0, duration_s=2.0)
    text = """\
robot_type: r
fps: 30
observations:
  - key: observation.pose
    topic: /pose
    type: geometry_msgs/msg/PoseStamped
    align: {strategy: interpolate}
"""
    summary = _convert(tmp_path / "pose", tmp_path / "st", text)
    names = next(f for f in summary.features if f.key == "observation.pose").names
    assert names is not None and names[3:] == tuple(f"pose.orientation.{c}" for c in "xyzw")
    values = _vectors(summary, "observation.pose")
    t = (_ticks(summary, "observation.pose") - stamps[0]) / NS
    np.testing.assert_allclose(
        values[:, :3], np.stack([2.0 * t, -t, np.full_like(t, 0.5)], axis=1), atol=1e-6
    )
    truth = _rotation(AXIS, OMEGA * t)
    # slerp is exact for a constant-rate rotation; blending 0.3 rad apart samples linearly is not
    np.testing.assert_allclose(values[:, 3:], truth, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(values[:, 3:], axis=1), 1.0, atol=1e-6)
    lo = np.floor(t * 10) / 10
    linear = (1 - (t - lo) * 10)[:, None] * _rotation(AXIS, OMEGA * lo) + ((t - lo) * 10)[
        :, None
    ] * _rotation(AXIS, OMEGA * (lo + 0.1))
    assert np.abs(linear - truth).max() > 1e-3


POSE_CONTRACT = """\
robot_type: r
fps: 30
observations:
  - key: observation.pose
    topic: /pose
    type: geometry_msgs/msg/PoseStamped
"""


@pytest.mark.parametrize(
    "header_ns", [lambda t: 0, lambda t: 1_700_000_000 * NS], ids=["zero-stamps", "constant-stamp"]
)
def test_untrustworthy_header_stamps_fall_back_to_receive_time(
    tmp_path: Path, header_ns: Callable[[int], int]
) -> None:
    stamps = _write_pose_bag(tmp_path / "pose", 10.0, 1.0, header_ns)
    summary = _convert(tmp_path / "pose", tmp_path / "st", POSE_CONTRACT)
    assert summary.stamp_sources == {"observation.pose@/pose": "receive"}
    prov = pq.read_table(Path(summary.dir_uri) / PROVENANCE_FILE).to_pylist()
    assert all(r["stamp_used"] == "receive" and r["source_log_ns"] - 1_000_000 in stamps for r in prov)
    explicit = POSE_CONTRACT + "    align: {stamp: header}\n"
    with pytest.raises(AlignmentError, match=r"align\.stamp is 'header' .* no usable header stamps"):
        _convert(tmp_path / "pose", tmp_path / "st2", explicit)


def test_disordered_stamps_are_counted_and_handled_deterministically(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        duration_s=1.0, cameras=(), task=None, faults=Faults(joint_out_of_order=2, joint_duplicate_stamps=3)
    )
    write_episode_bag(tmp_path / "ep", "mcap", spec)
    text = _contract().replace("{strategy: interpolate}\nactions", "{strategy: hold}\nactions")
    first = _converts_identically(tmp_path, text)
    checks = _qa_values(first, "/joint_states")
    assert checks["time.out_of_order"]["value"] == 2 and checks["time.duplicate_stamps"]["value"] == 3
    # hold picks the largest stamp at or before the tick, whatever the log order
    prov = [
        r
        for r in pq.read_table(Path(first.dir_uri) / PROVENANCE_FILE).to_pylist()
        if r["key"] == "observation.state"
    ]
    assert all(0 <= r["tick_ns"] - r["source_header_ns"] < 10_000_000 for r in prov)


def _converts_identically(tmp_path: Path, text: str) -> EpisodeSummary:
    """Convert ``tmp_path/ep`` twice; the frames must be the same both times (deterministic handling)."""
    first = _convert(tmp_path / "ep", tmp_path / "a", text)
    again = _convert(tmp_path / "ep", tmp_path / "b", text)
    assert pq.read_table(Path(first.dir_uri) / FRAMES_FILE).equals(
        pq.read_table(Path(again.dir_uri) / FRAMES_FILE)
    )
    return first


def _qa_values(summary: EpisodeSummary, subject: str) -> dict[str, Any]:
    qa = json.loads((Path(summary.dir_uri) / QA_FILE).read_text())
    return {c["check"]: c for c in qa["checks"] if c["subject"] == subject}


def test_header_stamps_ahead_of_receive_time_are_tolerated_and_reported(tmp_path: Path) -> None:
    """Another machine's clock 200 ms ahead, not corrected: no reset, no zero-fill; the offset is in QA."""
    spec = EpisodeSpec(
        duration_s=2.0, cameras=(), task=None, seed=5, faults=Faults(joint_header_ahead_ns=200_000_000)
    )
    truth = write_episode_bag(tmp_path / "ep", "mcap", spec)
    summary = _convert(tmp_path / "ep", tmp_path / "s", _contract())
    ticks = _ticks(summary, "observation.state")
    state = _vectors(summary, "observation.state")
    # every frame holds the sample whose (shifted) header stamp is the tick: captured 200 ms earlier
    assert summary.frames == ticks.size >= 50
    assert np.all(np.abs(state).sum(axis=1) > 0)
    np.testing.assert_allclose(state, truth.joint_position(ticks - 200_000_000), atol=_bound(100))
    report = next(r for r in summary.alignment if r["key"] == "observation.state")
    assert report["filled_frames"] == 0 and report["stamp"] == "header"
    offset = _qa_values(summary, "/joint_states")["time.clock_offset_ms"]
    assert offset["value"] == pytest.approx(200 - 2, abs=0.5)  # 2 ms recorder latency
    assert offset["verdict"] != "pass"


def test_a_clock_jump_is_counted_and_converts_the_same_every_time(tmp_path: Path) -> None:
    """Joint header stamps jump 2 s ahead mid-episode (QA's threshold: 1 s): a hard QA failure, and the
    same frames on every conversion."""
    spec = EpisodeSpec(duration_s=2.0, cameras=(), task=None, faults=Faults(joint_clock_jump_s=2.0))
    write_episode_bag(tmp_path / "ep", "mcap", spec)
    first = _converts_identically(
        tmp_path, _contract().replace("{strategy: interpolate}", "{strategy: hold}")
    )
    jumps = _qa_values(first, "/joint_states")["time.clock_jumps"]
    assert (jumps["value"], jumps["verdict"]) == (1, "fail")
    assert np.isfinite(_vectors(first, "observation.state")).all()
