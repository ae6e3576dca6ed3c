"""Each QA check against a bag built to trip it, and a clean bag that passes them all."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from bagport.episode import EpisodeRequest, convert_episode
from bagport.episode.score import score_bag
from bagport.qa import CheckResult, EpisodeQA, QAConfig
from bagport.synth import EpisodeSpec, Faults, Window, write_episode_bag
from tests.helpers import FAST_SETTINGS, SAMPLE_CONTRACT, SMALL_CAMERAS

BASE = EpisodeSpec(duration_s=3.0, cameras=SMALL_CAMERAS, mcap_crcs=True)  # checksummed: no integrity warning


def _request(
    bag: Path,
    tmp_path: Path,
    qa: QAConfig | None = None,
    task: str | None = None,
    contract: str | None = None,
) -> EpisodeRequest:
    return EpisodeRequest(
        episode_id="ep",
        bag_uri=str(bag),
        manifest_entry=0,
        staging_uri=str(tmp_path / "staging"),
        contract_text=contract or SAMPLE_CONTRACT.read_text(),
        contract_name="sample_robot.yaml",
        encoder=FAST_SETTINGS,
        default_task=task,
        qa=qa or QAConfig(),
    )


def _score(tmp_path: Path, spec: EpisodeSpec, qa: dict[str, Any] | None = None) -> EpisodeQA:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", spec)
    return score_bag(_request(bag, tmp_path, QAConfig.model_validate(qa or {})))


def _check(result: EpisodeQA, check: str, subject: str) -> CheckResult:
    found = [c for c in result.checks if c.check == check and c.subject == subject]
    assert len(found) == 1, f"{check} {subject}: {[(c.check, c.subject) for c in result.checks]}"
    return found[0]


def _problems(result: EpisodeQA) -> set[tuple[str, str, str]]:
    return {(c.check, c.subject, c.verdict) for c in result.problems}


def test_clean_episode_passes_every_check_including_images(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", replace(BASE, faults=Faults()))
    summary = convert_episode(_request(bag, tmp_path))
    qa = EpisodeQA.from_dict(json.loads((Path(summary.dir_uri) / "qa.json").read_text()))
    assert qa.problems == []
    assert (qa.verdict, qa.score) == ("pass", 1.0)
    assert summary.qa["verdict"] == "pass"
    assert _check(qa, "time.output_monotonic", "episode").value == 0
    groups = {c.check.split(".")[0] for c in qa.checks}
    assert groups == {"coverage", "rates", "time", "values", "content", "integrity", "video"}
    fidelity = qa.plots["fidelity"]
    assert set(fidelity) == {"observation.images.front", "observation.images.wrist"}
    for key, clip in fidelity.items():
        assert clip["frames_ok"] and clip["pts_ok"] and clip["sampled_frames"] > 0, key
        assert "worst_jpeg_base64" not in clip  # only shown when a video check did not pass
    assert {c.subject for c in qa.checks if c.check == "values.frozen_image_s"} == {
        "observation.images.front",
        "observation.images.wrist",
    }
    assert qa.plots["streams"]["/front/image_raw"]["count"] > 80


def test_camera_dropout_is_a_gap_with_dropped_frames(tmp_path: Path) -> None:
    spec = replace(BASE, faults=Faults(camera_dropout=Window(1.0, 0.3, "front")))
    result = _score(tmp_path, spec)
    gap = _check(result, "rates.gap_periods", "/front/image_raw")
    assert gap.verdict == "warn"
    assert 9.5 <= gap.value <= 11.5
    assert "at 0.9" in gap.reason or "at 1.0" in gap.reason
    dropped = _check(result, "rates.dropped_frames", "/front/image_raw")
    assert 8 <= dropped.value <= 10
    assert _check(result, "rates.gap_periods", "/wrist/image_raw/compressed").verdict == "pass"


def test_low_rate_against_the_nominal_rate(tmp_path: Path) -> None:
    qa = {
        "rates": {
            "nominal_hz": {"/front/image_raw": 60},
            "rate_ratio": {"warn": 0.95, "fail": 0.8, "hard": True},
        }
    }
    result = _score(tmp_path, BASE, qa)
    ratio = _check(result, "rates.rate_ratio", "/front/image_raw")
    assert ratio.verdict == "fail"
    assert ratio.value == pytest.approx(0.5, abs=0.02)
    assert result.verdict == "fail"


def test_jitter(tmp_path: Path) -> None:
    cameras = (replace(SMALL_CAMERAS[0], jitter_ns=16_000_000), SMALL_CAMERAS[1])
    result = _score(tmp_path, replace(BASE, cameras=cameras))
    assert _check(result, "rates.jitter", "/front/image_raw").verdict == "warn"
    assert _check(result, "rates.jitter", "/wrist/image_raw/compressed").verdict == "pass"


def test_short_episode(tmp_path: Path) -> None:
    result = _score(tmp_path, replace(BASE, duration_s=1.0))
    assert _check(result, "coverage.min_duration_s", "episode").verdict == "warn"


def test_nan_fails_the_episode_and_says_when(tmp_path: Path) -> None:
    result = _score(tmp_path, replace(BASE, faults=Faults(joint_nan_at_s=1.5)))
    check = _check(result, "values.non_finite", "observation.state")
    assert check.verdict == "fail"
    assert check.value >= 6
    assert "first at frame" in check.reason
    assert result.verdict == "fail"
    assert "values.non_finite observation.state" in result.headline()


def test_limits_and_kinematic_violation(tmp_path: Path) -> None:
    qa = {"values": {"limits": {"observation.state": [-5, 5]}, "max_velocity": {"observation.state": 6.0}}}
    clean = _score(tmp_path / "a", BASE, qa)
    assert _check(clean, "values.out_of_limits", "observation.state").verdict == "pass"
    assert _check(clean, "values.velocity_violations", "observation.state").verdict == "pass"
    spiked = _score(tmp_path / "b", replace(BASE, faults=Faults(joint_spike=(1.0, 8.0))), qa)
    assert _check(spiked, "values.out_of_limits", "observation.state").verdict == "fail"
    assert _check(spiked, "values.velocity_violations", "observation.state").value >= 2


def test_frozen_state(tmp_path: Path) -> None:
    spec = replace(BASE, faults=Faults(frozen_joints=Window(0.5, 1.5)))
    result = _score(tmp_path, spec, {"values": {"frozen_state_s": {"warn": 1.0}}})
    check = _check(result, "values.frozen_state_s", "observation.state")
    assert check.verdict == "warn"
    assert check.value == pytest.approx(1.5, abs=0.1)
    assert _check(result, "values.frozen_state_s", "action").verdict == "pass"


def test_clock_offset_between_machines_is_reported_not_fatal(tmp_path: Path) -> None:
    result = _score(tmp_path, replace(BASE, faults=Faults(joint_header_ahead_ns=20_000_000)))
    check = _check(result, "time.clock_offset_ms", "/joint_states")
    assert check.verdict == "warn"
    assert check.value == pytest.approx(18.0, abs=0.5)


def test_out_of_order_and_duplicate_stamps(tmp_path: Path) -> None:
    spec = replace(BASE, faults=Faults(joint_out_of_order=2, joint_duplicate_stamps=3))
    result = _score(tmp_path, spec)
    assert _check(result, "time.out_of_order", "/joint_states").value == 2
    assert _check(result, "time.duplicate_stamps", "/joint_states").value == 3
    assert _check(result, "time.out_of_order", "/cmd").value == 0


def test_clock_jump(tmp_path: Path) -> None:
    result = _score(tmp_path, replace(BASE, faults=Faults(joint_clock_jump_s=5.0)))
    check = _check(result, "time.clock_jumps", "/joint_states")
    assert (check.verdict, check.value) == ("fail", 1)


def test_recorder_delay_and_camera_action_gap(tmp_path: Path) -> None:
    cameras = (replace(SMALL_CAMERAS[0], latency_ns=150_000_000), SMALL_CAMERAS[1])
    result = _score(tmp_path, replace(BASE, cameras=cameras, action_rate_hz=4.0))
    delay = _check(result, "time.delay_p95_ms", "/front/image_raw")
    assert delay.verdict == "warn"
    assert delay.value == pytest.approx(150.0, abs=1.0)
    gap = _check(result, "time.camera_action_gap_share", "observation.images.front")
    assert gap.verdict == "warn"  # soft by default: a warning, not an exclusion
    assert gap.value > 0.5


def test_safety_topic_active_inside_the_episode(tmp_path: Path) -> None:
    result = _score(tmp_path, replace(BASE, faults=Faults(estop_at_s=2.0)), {"safety": {"topic": "/estop"}})
    check = _check(result, "safety.active", "/estop")
    assert check.verdict == "fail"
    assert "2.0" in check.reason
    calm = _score(
        tmp_path / "calm", replace(BASE, faults=Faults(estop_at_s=9.0)), {"safety": {"topic": "/estop"}}
    )
    assert _check(calm, "safety.active", "/estop").verdict == "pass"


def test_missing_task_prompt(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", replace(BASE, task=None))
    without_task_topic = SAMPLE_CONTRACT.read_text().split("\ntasks:")[0]
    result = score_bag(_request(bag, tmp_path, contract=without_task_topic))
    assert _check(result, "content.task_missing", "episode").verdict == "fail"
    with_manifest_task = score_bag(
        _request(bag, tmp_path, task="stack the cups", contract=without_task_topic)
    )
    assert _check(with_manifest_task, "content.task_missing", "episode").verdict == "pass"


def test_unreadable_bag_gets_a_failing_record_with_the_reason(tmp_path: Path) -> None:
    spec = replace(BASE, cameras=(SMALL_CAMERAS[0],))
    result = _score(tmp_path, spec)
    assert result.verdict == "fail"
    assert result.error is not None
    assert "/wrist/image_raw/compressed" in result.error


@pytest.mark.parametrize(
    ("faults", "check", "subject"),
    [
        (
            Faults(black_frames=Window(1.0, 0.5, "front")),
            "values.dark_or_bright_frames",
            "observation.images.front",
        ),
        (
            Faults(frozen_camera=Window(0.5, 1.5, "wrist")),
            "values.frozen_image_s",
            "observation.images.wrist",
        ),
    ],
)
def test_image_content_checks_during_conversion(
    tmp_path: Path, faults: Faults, check: str, subject: str
) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", replace(BASE, faults=faults))
    summary = convert_episode(_request(bag, tmp_path))
    qa = EpisodeQA.from_dict(json.loads((Path(summary.dir_uri) / "qa.json").read_text()))
    found = _check(qa, check, subject)
    assert found.verdict == "warn"
    assert found.value >= (14 if check.endswith("frames") else 1.4)
    assert summary.qa["verdict"] == "warn"


@pytest.mark.parametrize(
    ("storage", "crcs", "says"),
    [
        ("mcap", False, r"MCAP without chunk CRCs .*Fix: record chunked MCAP with CRCs: .*`noCRC: false`"),
        (
            "sqlite3",
            False,
            r"rosbag2 SQLite \(\.db3\) bags carry no checksums.*Fix: record with `ros2 bag record -s mcap`",
        ),
        ("ros1", False, r"ROS 1 bags carry no checksums.*Fix: "),
        ("mcap", True, r"checksums verified on read: MCAP chunk CRC-32s"),
    ],
    ids=["mcap-without-crcs", "sqlite3", "ros1", "mcap-with-crcs"],
)
def test_a_bag_without_checksums_is_a_warning_that_does_not_fail_the_episode(
    tmp_path: Path, storage: str, crcs: bool, says: str
) -> None:
    bag = tmp_path / ("ep.bag" if storage == "ros1" else "ep")
    write_episode_bag(bag, storage, replace(BASE, mcap_crcs=crcs))  # type: ignore[arg-type]
    result = score_bag(_request(bag, tmp_path))
    check = _check(result, "integrity.unchecked", "bag")
    assert re.search(says, check.reason), check.reason
    assert (check.verdict, check.hard) == (("pass", False) if crcs else ("warn", False))
    assert result.verdict == ("pass" if crcs else "warn")  # a warning, never a failure


def test_a_converted_episode_carries_the_no_checksum_warning(tmp_path: Path) -> None:
    bag = tmp_path / "ep.bag"
    write_episode_bag(bag, "ros1", replace(BASE, duration_s=1.5))
    summary = convert_episode(_request(bag, tmp_path))
    qa = EpisodeQA.from_dict(json.loads((Path(summary.dir_uri) / "qa.json").read_text()))
    check = _check(qa, "integrity.unchecked", "bag")
    assert check.verdict == "warn" and "ROS 1 bags carry no checksums" in check.reason
    assert summary.qa["verdict"] == "warn"
