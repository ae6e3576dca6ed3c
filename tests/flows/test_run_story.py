"""The counts a run's last line, its artifacts and its flow-run name give (flows/run_story.py)."""

from __future__ import annotations

from dataclasses import replace

from bagport.dataset import DatasetReport
from bagport.qa import QABrief
from bagport.qa.result import Verdict
from flows.run_story import RunCounts


def _brief(n: int, verdict: Verdict, index: int | None) -> QABrief:
    return QABrief(
        bag_uri=f"/bags/ep{n}",
        manifest_entry=n,
        episode_index=index,
        score={"pass": 1.0, "warn": 0.8, "fail": 0.2}[verdict],
        verdict=verdict,
        excluded=index is None,
        reason="" if verdict == "pass" else f"{verdict} reason",
        duration_s=2.0,
        frames=60,
        video_psnr_min_db=None,
        video_damaged_frames=None,
        segment=None,
        label=None,
        note="",
        excluded_by_label=False,
        metadata={},
    )


def _report(*briefs: QABrief) -> DatasetReport:
    excluded = tuple(b for b in briefs if b.episode_index is None)
    return DatasetReport("/out", 3, 180, ("task",), (), 0, 6.0, excluded=excluded, qa=briefs, converted=3)


def test_an_episode_kept_although_qa_failed_it_is_counted_and_said() -> None:
    report = _report(
        _brief(0, "pass", 0), _brief(1, "warn", 1), _brief(2, "fail", 2), _brief(3, "fail", None)
    )
    counts = RunCounts.of(report)
    assert (counts.converted, counts.warned, counts.failed_kept, counts.excluded) == (3, 1, 1, 1)
    assert counts.text() == (
        "3 episode(s) converted (1 with QA warnings, 1 kept although QA failed them), 1 excluded"
    )


def test_without_kept_failures_the_text_does_not_mention_them() -> None:
    counts = RunCounts.of(_report(_brief(0, "warn", 0), _brief(1, "fail", None)))
    assert counts.failed_kept == 0
    assert counts.text() == "1 episode(s) converted (1 with QA warnings), 1 excluded"


def test_reused_counts_the_written_episodes_that_came_from_the_staging_store() -> None:
    """A reused episode a label or QA excluded is among the excluded, not among the written ones."""
    report = _report(_brief(0, "pass", 0), _brief(1, "warn", 1), _brief(2, "fail", None))
    counts = RunCounts.of(replace(report, reused=("/bags/ep0", "/bags/ep2")))
    assert (counts.converted, counts.reused, counts.excluded) == (2, 1, 1)
    assert (
        counts.text()
        == "2 episode(s) converted (1 reused from the staging store, 1 with QA warnings), 1 excluded"
    )
