"""What one run did, told where people look: counts of this run's episodes, the state name in run
lists ("Completed with exclusions"), and a distinct run name for scheduled runs.

The dataset report describes the whole dataset (an append's totals); :class:`RunCounts` counts only
the episodes of this run, from its QA rows.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from prefect.client.schemas.objects import State
from prefect.states import Completed

from bagport.dataset import DatasetReport
from bagport.qa import episode_ref

__all__ = ["EXCLUSIONS_STATE", "RunCounts", "completed_state", "started_name"]

EXCLUSIONS_STATE = "Completed with exclusions"
"""The state name of a run that wrote its dataset but left bags out (red flags in every run list)."""


@dataclass(frozen=True, slots=True)
class RunCounts:
    """Episodes of this run: written, of which reused from the staging store, warned by QA and kept although
    QA failed them (``--on-qa-fail keep``), and excluded (QA, conversion, label)."""

    converted: int
    warned: int
    excluded: int
    reused: int = 0
    failed_kept: int = 0

    @classmethod
    def of(cls, report: DatasetReport) -> RunCounts:
        kept = [row for row in report.qa if row.episode_index is not None]
        reused = Counter(report.reused)  # every reused episode, an excluded one (its label, its QA) too
        reused_kept = 0
        for row in kept:
            ref = episode_ref(row.bag_uri, row.segment)
            if reused[ref]:
                reused[ref] -= 1
                reused_kept += 1
        return cls(
            converted=len(kept),
            warned=sum(row.verdict == "warn" for row in kept),
            excluded=len(report.excluded),
            reused=reused_kept,
            failed_kept=sum(row.verdict == "fail" for row in kept),
        )

    def text(self) -> str:
        reused = f"{self.reused} reused from the staging store, " if self.reused else ""
        failed = f", {self.failed_kept} kept although QA failed them" if self.failed_kept else ""
        return (
            f"{self.converted} episode(s) converted ({reused}{self.warned} with QA warnings{failed}), "
            f"{self.excluded} excluded"
        )


def completed_state(report: DatasetReport) -> DatasetReport | State[Any]:
    """The flow's return: the report, or a Completed state named for its exclusions."""
    counts = RunCounts.of(report)
    if not counts.excluded:
        return report
    return Completed(name=EXCLUSIONS_STATE, message=counts.text(), data=report)


def started_name(kind: str) -> str:
    """``<kind> <UTC time>``: the name a scheduled run starts with (the count is added when it ends)."""
    return f"{kind} {datetime.now(UTC):%Y-%m-%d %H:%M:%S}"
