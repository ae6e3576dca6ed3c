"""End to end against the analytic truth: jittered 30 Hz cameras, 500 Hz joints, 50 Hz actions, header
latency, a 300 ms camera dropout and a clock offset between machines, loaded back with LeRobot."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from bagport.dataset import write_dataset
from bagport.dataset.validate import video_backend
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.staging import QA_FILE, EpisodeSummary
from bagport.synth import (
    CameraSpec,
    EpisodeSpec,
    Faults,
    GroundTruth,
    Window,
    decode_frame_index,
    write_episode_bag,
)
from tests.helpers import FAST_SETTINGS

pytestmark = pytest.mark.slow

NS = 1_000_000_000
FPS = 30
AHEAD_MS = 200.0  # the arm computer's clock runs this far ahead of the recording machine's
PUBLISH_LAG_NS = 500_000  # publish_time = capture + 0.5 ms; receive (log) time = capture + latency
ACTION_OFFSET_MS = 20.0
SPEC = EpisodeSpec(
    duration_s=2.0,
    joint_rate_hz=500.0,
    action_rate_hz=50.0,
    cameras=(
        CameraSpec("front", "raw", "bgr8", jitter_ns=3_000_000, latency_ns=25_000_000),
        CameraSpec("wrist", "jpeg", jitter_ns=3_000_000, latency_ns=18_000_000),
    ),
    faults=Faults(
        camera_dropout=Window(0.8, 0.3, "front"), joint_header_ahead_ns=round(AHEAD_MS * 1_000_000)
    ),
    publish_lag_ns=PUBLISH_LAG_NS,
    seed=7,
)
CONTRACT = f"""\
robot_type: r
fps: {FPS}
action_offset_ms: {ACTION_OFFSET_MS}
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
    align: {{strategy: interpolate, clock_offset_ms: {AHEAD_MS}}}
  - key: observation.velocity
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [velocity.j1, velocity.j2, velocity.j3, velocity.j4, velocity.j5, velocity.j6]}}
    align: {{strategy: hold, clock_offset_ms: {AHEAD_MS}}}
  - key: observation.images.front
    topic: /front/image_raw
    type: sensor_msgs/msg/Image
    align: {{strategy: asof, tol_ms: 40, fill: hold}}
  - key: observation.images.wrist
    topic: /wrist/image_raw/compressed
    type: sensor_msgs/msg/CompressedImage
    align: {{strategy: nearest, tol_ms: 20}}
actions:
  - key: action
    publish: {{topic: /cmd, type: sensor_msgs/msg/JointState}}
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
    align: {{strategy: interpolate, stamp: publish}}
"""
# linear interpolation between samples h apart errs by at most max|q''| h^2 / 8 (amplitude <= 1 rad,
# frequency <= 0.5 Hz); float32 storage adds ~1e-7
CURVATURE = (2 * np.pi * 0.5) ** 2


def _bound(rate_hz: float) -> float:
    return CURVATURE * (1 / rate_hz) ** 2 / 8 + 1e-6


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[GroundTruth, EpisodeSummary, Path]:
    root = tmp_path_factory.mktemp("timetruth")
    truth = write_episode_bag(root / "ep", "mcap", SPEC)
    summary = convert_episode(
        EpisodeRequest(
            episode_id_for(str(root / "ep"), CONTRACT, FAST_SETTINGS),
            str(root / "ep"),
            0,
            str(root / "staging"),
            CONTRACT,
            "c.yaml",
            FAST_SETTINGS,
            "t",
        )
    )
    write_dataset([summary], str(root / "ds"), robot_type="r")
    return truth, summary, root / "ds"


def _kept_camera_stamps(truth: GroundTruth, name: str) -> Any:
    stamps = truth.camera_stamps_ns(name)
    dropout = SPEC.faults.camera_dropout
    if dropout is None or dropout.camera != name:
        return np.arange(stamps.size), stamps
    kept = np.array([not dropout.contains(int(s), SPEC.start_ns) for s in stamps])
    return np.flatnonzero(kept), stamps[kept]


def test_lerobot_loaded_dataset_matches_the_truth_within_each_strategys_tolerance(
    converted: tuple[GroundTruth, EpisodeSummary, Path],
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    truth, summary, out = converted
    dataset = LeRobotDataset("test/time", root=out, video_backend=video_backend())
    assert len(dataset) == summary.frames > 50
    joint_capture = truth.joint_stamps_ns()
    front_index, front_stamps = _kept_camera_stamps(truth, "front")
    wrist_index, wrist_stamps = _kept_camera_stamps(truth, "wrist")
    offset_ns = round(ACTION_OFFSET_MS * 1e6) - PUBLISH_LAG_NS
    errors = {"state": 0.0, "action": 0.0}
    for k in range(len(dataset)):
        item = dataset[k]
        tick = summary.first_tick_ns + k * NS // FPS
        assert abs(float(item["timestamp"]) - k / FPS) < 1e-6
        # interpolate, on the arm's clock corrected by clock_offset_ms: the state at the true tick time
        errors["state"] = max(
            errors["state"],
            float(np.abs(item["observation.state"].numpy() - truth.joint_position(tick)).max()),
        )
        # hold: the newest sample captured at or before the tick, never one from the future
        held = joint_capture[np.searchsorted(joint_capture, tick, side="right") - 1]
        np.testing.assert_allclose(
            item["observation.velocity"].numpy(), truth.joint_velocity(held), atol=1e-5
        )
        # the action at tick t is the command published at t + action_offset_ms (publish = capture + lag)
        errors["action"] = max(
            errors["action"],
            float(np.abs(item["action"].numpy() - truth.action_position(tick + offset_ns)).max()),
        )
        front = _code(item["observation.images.front"])
        assert front == front_index[np.searchsorted(front_stamps, tick, side="right") - 1] % 1024
        wrist = _code(item["observation.images.wrist"])
        nearest = int(np.argmin(np.abs(wrist_stamps - tick)))
        assert abs(int(wrist_stamps[nearest]) - tick) <= 20_000_000
        assert wrist == wrist_index[nearest] % 1024
    assert errors["state"] < _bound(SPEC.joint_rate_hz)
    assert errors["action"] < _bound(SPEC.action_rate_hz)


def _code(chw: Any) -> int:
    rgb = (chw.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    return decode_frame_index(rgb)


def _checks(summary: EpisodeSummary) -> dict[tuple[str, str], dict[str, Any]]:
    qa = json.loads((Path(summary.dir_uri) / QA_FILE).read_text())
    return {(c["check"], c["subject"]): c for c in qa["checks"]}


def test_dropout_and_clock_offset_show_up_in_qa_not_as_silent_frozen_frames(
    converted: tuple[GroundTruth, EpisodeSummary, Path],
) -> None:
    _, summary, out = converted
    checks = _checks(summary)
    dropped = checks[("rates.dropped_frames", "/front/image_raw")]
    assert dropped["verdict"] == "warn" and 7 <= dropped["value"] <= 10
    filled = checks[("time.filled_frames", "observation.images.front@/front/image_raw")]
    # 300 ms without images, the first 40 ms of it still within tol_ms: ~8 frames held, and said so
    assert filled["verdict"] == "warn" and 6 <= filled["value"] <= 9
    assert (
        checks[("time.filled_frames", "observation.images.wrist@/wrist/image_raw/compressed")]["value"] == 0
    )
    offset = checks[("time.clock_offset_ms", "/joint_states")]
    assert offset["verdict"] == "warn" and abs(offset["value"] - (AHEAD_MS - 2.0)) < 0.5  # minus 2 ms latency
    prov = pq.read_table(out / "meta/provenance/chunk-000/file-000.parquet").to_pylist()
    front = [r for r in prov if r["key"] == "observation.images.front"]
    assert sum(r["fill"] == "hold" for r in front) == filled["value"]
    for r in front:
        if r["fill"] is None:
            assert 0 <= r["tick_ns"] - r["source_header_ns"] <= 40_000_000


def test_alignment_report_in_provenance_and_qa(converted: tuple[GroundTruth, EpisodeSummary, Path]) -> None:
    _, summary, out = converted
    run = json.loads((out / "meta/provenance/run.json").read_text())
    report = {r["key"]: r for r in run["episodes"][0]["alignment"]}
    assert report["action"]["stamp"] == "publish" and report["action"]["offset_ms"] == ACTION_OFFSET_MS
    assert report["observation.state"]["offset_ms"] == AHEAD_MS
    assert report["observation.state"]["interpolated_frames"] == summary.frames
    assert report["observation.images.wrist"]["error_ms"]["max"] <= 20
    # asof: error below tol_ms on frames with a fresh image; the held frames are counted, not hidden
    assert report["observation.images.front"]["error_ms"]["max"] <= 40
    checks = _checks(summary)
    for key, entry in report.items():
        check = checks[("time.alignment_error_p95_ms", f"{key}@{entry['topic']}")]
        assert check["value"] == pytest.approx(entry["error_ms"]["p95"])
    prov = pq.read_table(out / "meta/provenance/chunk-000/file-000.parquet").to_pylist()
    action = [r for r in prov if r["key"] == "action"]
    # the receive time is kept beside the publish time that was used
    assert all(r["stamp_used"] == "publish" for r in action)
    assert all(r["source_log_ns"] - r["source_publish_ns"] == 500_000 for r in action)
