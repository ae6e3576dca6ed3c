"""The score orders episodes by severity: any hard failure below any warning, any warning below a pass."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from bagport.qa import CheckResult, EpisodeQA, QAEntry, Verdict, score_checks


def _checks(verdicts: list[Verdict]) -> list[CheckResult]:
    return [CheckResult(f"g.c{i}", "x", 0.0, v, v == "fail", "r") for i, v in enumerate(verdicts)]


verdict_lists = st.lists(st.sampled_from(["pass", "warn", "fail"]), min_size=1, max_size=60)


@given(a=verdict_lists, b=verdict_lists)
def test_score_orders_by_severity_first(a: list[Verdict], b: list[Verdict]) -> None:
    rank = {"fail": 0, "warn": 1, "pass": 2}
    score_a, verdict_a = score_checks(_checks(a))
    score_b, verdict_b = score_checks(_checks(b))
    if rank[verdict_a] < rank[verdict_b]:
        assert score_a < score_b
    assert 0.0 <= score_a <= 1.0


def test_a_nan_joint_failure_scores_below_a_warned_episode() -> None:
    # the case that misled a supervisor: 1 hard failure in 50 checks scored 0.98, above a warning's 0.96
    fail: list[Verdict] = ["fail"]
    warn: list[Verdict] = ["warn", "warn"]
    passes: list[Verdict] = ["pass"]
    failed = score_checks(_checks(fail + passes * 49))
    warned = score_checks(_checks(warn + passes * 23))
    assert failed[1] == "fail" and warned[1] == "warn"
    assert failed[0] < 0.4
    assert 0.5 <= warned[0] < 0.9
    assert score_checks(_checks(passes * 3)) == (1.0, "pass")


def test_a_brief_is_one_typed_row_whose_json_is_the_summary_shape() -> None:
    """``QAEntry.brief`` gives a :class:`QABrief`; its JSON has the run summary's keys in their order,
    ``source_stamp`` only once the run record sets it."""
    qa = EpisodeQA.failed("s3://fleet/day1/ep_7.mcap", "gone: bag does not exist")
    entry = QAEntry(qa, 3, None, "conversion failed: gone", segment=2, metadata={"robot_id": "arm-1"})
    brief = entry.brief()
    assert (brief.name, brief.excluded, brief.reason) == ("ep_7.mcap#2", True, "conversion failed: gone")
    assert list(brief.to_json()) == [
        "bag_uri", "manifest_entry", "episode_index", "score", "verdict", "excluded", "reason", "duration_s",
        "frames", "video_psnr_min_db", "video_damaged_frames", "segment", "label", "note", "excluded_by_label",
        "metadata",
    ]  # fmt: skip
    stamped = replace(brief, source_stamp="size:1").to_json()
    assert list(stamped)[-1] == "source_stamp"
    assert stamped["metadata"] == {"robot_id": "arm-1"}


def test_a_staged_entry_holds_a_digest_and_reads_its_record_back(tmp_path: Path) -> None:
    checks = [
        CheckResult("rates.rate_ratio", "/joint_states", 0.98, "pass", False, "98 of 100"),
        CheckResult("coverage.min_duration_s", "episode", 0.97, "warn", True, "lasts 0.97 s"),
        CheckResult("values.jumps", "action", 0.1, "pass", False, "small"),
    ]
    plots = {
        "window_ns": [1, 2],
        "thumbnails": {"observation.images.front": [{"t_s": 0.0, "jpeg": "A" * 4000}]},
        "vectors": {"action": [[0.0, 1.0]]},
        "fidelity": {"observation.images.front": {"psnr_min_db": 41.5, "damaged_frames": 1, "psnr_db_per_frame": [41.5]}},
    }  # fmt: skip
    record = EpisodeQA.build("/bags/a.mcap", checks, duration_s=0.97, frames=29, plots=plots)
    uri = tmp_path / "qa.json"
    uri.write_text(json.dumps(record.to_dict()))
    full = QAEntry(record, 4, 0)
    entry = replace(QAEntry.of_staged(EpisodeQA.read(str(uri)), str(uri), 4), episode_index=0)

    assert "thumbnails" not in entry.qa.plots and "vectors" not in entry.qa.plots  # held per episode: small
    assert entry.qa.checks == record.problems
    assert entry.brief() == full.brief()  # the index, summary and run record see the same
    assert entry.whole() == full
    extra = [
        CheckResult("values.step_outlier", "action", 9.0, "warn", False, "a jump"),
        CheckResult("values.step_outlier", "observation.state", 1.0, "pass", False, "fine"),
    ]
    assert entry.with_checks(extra).qa.score == full.with_checks(extra).qa.score
    assert entry.with_checks(extra).whole() == full.with_checks(extra)
    assert full.whole() is full


def test_to_dict_is_asdict_without_copying_the_plots() -> None:
    checks = [CheckResult("values.jumps", "action", 0.1, "warn", False, "a jump")]
    plots = {
        "vectors": {"action": [[0.0, 1.0], [2.0, 3.0]]},
        "thumbnails": {"front": [{"frame": 0, "jpeg": "A"}]},
    }
    record = EpisodeQA.build("/bags/a.mcap", checks, duration_s=1.5, frames=45, plots=plots)
    as_dict = record.to_dict()
    assert as_dict == asdict(record)
    assert json.dumps(as_dict) == json.dumps(asdict(record))  # qa.json byte for byte, keys in order
    assert EpisodeQA.from_dict(json.loads(json.dumps(as_dict))) == record


def test_a_reason_names_the_limit_the_value_crossed() -> None:
    """A soft check past its fail limit warns, and says it crossed the fail limit (not "warn limit 0.8")."""
    from bagport.qa import judge  # noqa: PLC0415
    from bagport.qa.config import Gate  # noqa: PLC0415

    soft, hard = Gate(warn=0.95, fail=0.8, hard=False), Gate(warn=0.95, fail=0.8)
    ratio = "65.0% of the expected messages"
    assert judge("rates.rate_ratio", "/t", 0.65, soft, ratio, lower_is_worse=True).reason == (
        f"{ratio} (at or below fail limit 0.8; a soft check, so it warns)"
    )
    assert judge("rates.rate_ratio", "/t", 0.65, hard, ratio, lower_is_worse=True).reason == (
        f"{ratio} (at or below fail limit 0.8)"
    )
    assert judge("rates.rate_ratio", "/t", 0.9, soft, ratio, lower_is_worse=True).reason == (
        f"{ratio} (at or below warn limit 0.95)"
    )
    assert judge("rates.gap_periods", "/t", 0.5, hard, "0.5 periods").reason == "0.5 periods"  # a pass
