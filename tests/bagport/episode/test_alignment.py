"""Alignment strategies and fill policies, end to end on synthetic bags with known truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq
import pytest

from bagport.columns import vector_column
from bagport.episode import convert_episode
from bagport.errors import AlignmentError
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, GroundTruth, write_episode_bag
from bagport.synth.faults import Window
from bagport.video import iter_frames
from tests.helpers import episode_request

NS = 1_000_000_000


def _convert(bag: Path, staging: Path, text: str) -> EpisodeSummary:
    return convert_episode(episode_request(bag, staging, text, task="t"))


def _state_contract(align: str) -> str:
    return f"""\
robot_type: r
fps: 30
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
    align: {{{align}}}
actions:
  - key: action
    publish: {{topic: /cmd, type: sensor_msgs/msg/JointState}}
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
"""


def _state(summary: EpisodeSummary) -> npt.NDArray[np.float64]:
    return vector_column(pq.read_table(Path(summary.dir_uri) / "frames.parquet"), "observation.state")


def _ticks(summary: EpisodeSummary) -> npt.NDArray[np.int64]:
    return summary.first_tick_ns + (np.arange(summary.frames, dtype=np.int64) * NS) // 30


@pytest.mark.parametrize("rate_hz", [100, 500, 1000], ids=lambda r: f"{r}Hz")
def test_interpolation_beats_nearest_and_hold_against_the_analytic_truth(
    tmp_path: Path, rate_hz: int
) -> None:
    spec = EpisodeSpec(duration_s=2.0, joint_rate_hz=rate_hz, cameras=(), task=None, seed=4)
    truth = write_episode_bag(tmp_path / "ep", "mcap", spec)
    period_ms = 1000 / rate_hz
    aligns = {
        "hold": "strategy: hold",
        "nearest": f"strategy: nearest, tol_ms: {period_ms}",
        "interpolate": "strategy: interpolate",
    }
    errors = {}
    for strategy, align in aligns.items():
        summary = _convert(tmp_path / "ep", tmp_path / strategy, _state_contract(align))
        errors[strategy] = np.abs(_state(summary) - truth.joint_position(_ticks(summary))).max()
        report = next(r for r in summary.alignment if r["key"] == "observation.state")
        assert report["strategy"] == strategy
        assert report["filled_frames"] == 0
        if strategy == "interpolate":
            assert report["interpolated_frames"] > summary.frames // 2
    # linear interpolation between samples h apart errs by at most max|q''| h^2 / 8
    # (amplitude <= 1 rad, frequency <= 0.5 Hz), plus float32 storage
    curvature_bound = (2 * np.pi * 0.5) ** 2 * (period_ms / 1000) ** 2 / 8
    assert errors["interpolate"] < curvature_bound + 1e-6
    assert errors["interpolate"] < errors["nearest"] / 20
    assert errors["nearest"] < errors["hold"]


def _paused_bag(tmp_path: Path) -> GroundTruth:
    """500 Hz joints with the recorder paused from 0.8 s to 1.3 s."""
    spec = EpisodeSpec(
        duration_s=2.0, joint_rate_hz=500, cameras=(), task=None, seed=4, pauses=(Window(0.8, 0.5),)
    )
    return write_episode_bag(tmp_path / "ep", "mcap", spec)


def test_interpolate_does_not_bridge_a_dropout(tmp_path: Path) -> None:
    """A 0.5 s silence on a 500 Hz stream is a dropout, not a straight line: missing, and fill decides."""
    truth = _paused_bag(tmp_path)
    with pytest.raises(AlignmentError, match=r"observation.state.*more than 66.6+\d* ms apart.*a dropout"):
        _convert(tmp_path / "ep", tmp_path / "fail", _state_contract("strategy: interpolate"))
    held = _convert(tmp_path / "ep", tmp_path / "hold", _state_contract("strategy: interpolate, fill: hold"))
    ticks = _ticks(held)
    stamps = truth.joint_stamps_ns()
    pause_ns = truth.spec.start_ns + np.array([0.8, 1.3]) * NS
    last_before, first_after = stamps[stamps < pause_ns[0]].max(), stamps[stamps >= pause_ns[1]].min()
    in_gap = (ticks > last_before) & (ticks < first_after)
    report = next(r for r in held.alignment if r["key"] == "observation.state")
    assert report["filled_frames"] == int(in_gap.sum()) > 10
    state = _state(held)
    # held: the last message before the pause, not a line drawn to the first message after it
    np.testing.assert_allclose(
        state[in_gap], np.broadcast_to(truth.joint_position(last_before), (int(in_gap.sum()), 6)), atol=1e-6
    )
    np.testing.assert_allclose(state[~in_gap], truth.joint_position(ticks[~in_gap]), atol=1e-4)
    # an explicit tol_ms bridges it, and the report says how far off that is
    bridged = _convert(
        tmp_path / "ep", tmp_path / "tol", _state_contract("strategy: interpolate, tol_ms: 600")
    )
    assert next(r for r in bridged.alignment if r["key"] == "observation.state")["filled_frames"] == 0


def _camera_contract(fill: str, extra: str = "") -> str:
    return f"""\
robot_type: r
fps: 30
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [j1]}}
  - key: observation.images.front
    topic: /front/image_raw
    type: sensor_msgs/msg/Image
    align: {{strategy: asof, tol_ms: 40, fill: {fill}}}
{extra}"""


@pytest.fixture(scope="module")
def slow_camera(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, GroundTruth]:
    root = tmp_path_factory.mktemp("slowcam")
    spec = EpisodeSpec(
        duration_s=1.5, cameras=(CameraSpec("front", "raw", rate_hz=5.0, jitter_ns=0),), task=None
    )
    return root / "ep", write_episode_bag(root / "ep", "mcap", spec)


def test_fill_hold_is_explicit_in_provenance_and_report(
    tmp_path: Path, slow_camera: tuple[Path, GroundTruth]
) -> None:
    bag, _ = slow_camera
    summary = _convert(bag, tmp_path / "st", _camera_contract("hold"))
    report = next(r for r in summary.alignment if r["key"] == "observation.images.front")
    prov = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    fills = [r["fill"] for r in prov if r["key"] == "observation.images.front"]
    assert report["filled_frames"] == fills.count("hold") > 0
    assert fills.count(None) == summary.frames - report["filled_frames"]


def test_fill_drop_frame_keeps_only_ticks_with_a_fresh_image(
    tmp_path: Path, slow_camera: tuple[Path, GroundTruth]
) -> None:
    bag, truth = slow_camera
    summary = _convert(bag, tmp_path / "st", _camera_contract("drop_frame"))
    prov = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    rows = [r for r in prov if r["key"] == "observation.images.front"]
    assert len(rows) == summary.frames
    assert all(0 <= r["tick_ns"] - r["source_header_ns"] <= 40_000_000 for r in rows)
    report = next(r for r in summary.alignment if r["key"] == "observation.images.front")
    assert report["dropped_frames"] > 0
    camera = truth.camera_stamps_ns("front")
    assert (
        summary.frames + report["dropped_frames"]
        == 1 + (min(camera[-1], truth.joint_stamps_ns()[-1]) - summary.first_tick_ns) * 30 // NS
    )


def test_fill_zeros_needs_a_size_and_gives_black_frames(
    tmp_path: Path, slow_camera: tuple[Path, GroundTruth]
) -> None:
    bag, _ = slow_camera
    from bagport.errors import ContractError  # noqa: PLC0415

    with pytest.raises(
        ContractError, match=r"fill 'zeros' on camera observation\.images\.front needs a known frame size"
    ):
        _convert(bag, tmp_path / "st", _camera_contract("zeros"))
    text = _camera_contract("zeros").replace("fill: zeros}", "fill: zeros}\n    image: {resize: [96, 128]}")
    summary = _convert(bag, tmp_path / "st", text)
    prov = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    zero_frames = {
        r["frame_index"] for r in prov if r["key"] == "observation.images.front" and r["fill"] == "zeros"
    }
    assert zero_frames
    for k, (_, rgb) in enumerate(iter_frames(Path(summary.dir_uri) / "videos/observation.images.front.mp4")):
        if k in zero_frames:
            assert rgb.max() < 20
        else:
            assert rgb.max() > 200


def test_an_episode_over_a_day_is_a_clock_step_refused_before_its_grid() -> None:
    """A node on sim time before /clock logs its first messages at time 0: the streams span 1970 to now, a grid
    of 17 billion ticks (a MemoryError) unless refused first, saying where the clock stepped."""
    from bagport.contract import parse_contract  # noqa: PLC0415
    from bagport.episode.alignment import align_sources  # noqa: PLC0415
    from bagport.episode.timeline import Timeline, TopicTimeline  # noqa: PLC0415

    now_ns = 1_700_000_000_000_000_000
    log_ns = np.array([0, 100_000_000, *(now_ns + k * 100_000_000 for k in range(20))], dtype=np.int64)
    plan = parse_contract(
        "robot_type: r\nfps: 10\nobservations:\n  - {key: s, topic: /level, type: std_msgs/msg/Float64}\n",
        "c",
    )
    timeline = Timeline(topics={"/level": TopicTimeline("/level", log_ns, None)}, tasks=())
    with pytest.raises(AlignmentError) as caught:
        align_sources(plan, timeline, "bag")
    said = str(caught.value)
    assert "the episode would last 1,700,000,002 s (1970-01-01 00:00:00 UTC to 2023-11-14" in said
    assert "no stream has a message from 1970-01-01 00:00:00 UTC to 2023-11-14 22:13:20 UTC" in said
    assert "Fix: convert the part after the step with a manifest window" in said


def test_a_silence_of_every_stream_over_a_minute_is_refused_before_encoding() -> None:
    """A recording paused for ten minutes (or a clock step): every frame across it would hold the values before
    it. Refused, saying where, with the contract's gap split as the fix; a 50 s silence still converts."""
    from bagport.contract import parse_contract  # noqa: PLC0415
    from bagport.episode.alignment import align_sources  # noqa: PLC0415
    from bagport.episode.timeline import Timeline, TopicTimeline  # noqa: PLC0415

    start_ns, step_ns = 1_700_000_000_000_000_000, 100_000_000
    plan = parse_contract(
        "robot_type: r\nfps: 10\nobservations:\n  - {key: s, topic: /level, type: std_msgs/msg/Float64}\n",
        "c",
    )

    def timeline(silence_s: int) -> Timeline:
        before = [start_ns + k * step_ns for k in range(10)]
        after = [before[-1] + silence_s * 1_000_000_000 + k * step_ns for k in range(10)]
        log_ns = np.array(before + after, dtype=np.int64)
        return Timeline(topics={"/level": TopicTimeline("/level", log_ns, None)}, tasks=())

    with pytest.raises(AlignmentError) as caught:
        align_sources(plan, timeline(600), "bag")
    said = str(caught.value)
    assert (
        "no stream has a message for 600 s, from 2023-11-14 22:13:20 UTC to 2023-11-14 22:23:20 UTC" in said
    )
    assert "Fix: split the bag at its silences (the contract's 'episodes: {gap_s: 5}'" in said
    assert align_sources(plan, timeline(50), "bag").ticks_ns.size == 10 * 50 + 19  # held across, as asked
