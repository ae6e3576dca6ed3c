"""Prefect artifacts on the conversion flow run: progress, the QA table, and a dataset summary.

They show in the Prefect UI on the flow run's Artifacts tab (and under Artifacts by key).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from uuid import UUID

from prefect.artifacts import (
    create_markdown_artifact,
    create_progress_artifact,
    create_table_artifact,
    update_progress_artifact,
)

from bagport.dataset import DatasetReport
from bagport.run import up_to_date
from flows.run_story import RunCounts

__all__ = ["LISTENERS", "Progress", "ProgressListener", "publish_run_artifacts", "qa_table"]


ProgressListener = Callable[[int, int], None]
LISTENERS: list[ProgressListener] = []
"""Called with (done, total) as episodes finish, in the flow's process (the CLI's progress bar)."""


class Progress:
    """A progress artifact updated as episodes finish; episodes reused from the staging store are
    counted apart (they are done before the run starts)."""

    def __init__(self, total: int, reused: int = 0) -> None:
        self._total = total
        self._reused = reused
        self._done = 0
        artifact_id = create_progress_artifact(0.0, key="bagport-progress", description=self._text())
        assert isinstance(artifact_id, UUID)  # sync context: Prefect returns the id, not a coroutine
        self._id = artifact_id

    def _text(self) -> str:
        reused = f"; {self._reused} reused from the staging store" if self._reused else ""
        # failed ones count as finished too: the summary tells which
        return f"{self._done} of {self._total} episode(s) finished{reused}"

    def add(self, episodes: int, reused: int = 0) -> None:
        """More episodes to convert (a bag was split into its episodes), and more found staged already."""
        self._total += episodes
        self._reused += reused
        update_progress_artifact(self._id, self._percent(), description=self._text())
        for listener in LISTENERS:  # the bar shows 0/N as soon as the episodes are known
            listener(self._done, self._total)

    def _percent(self) -> float:
        return 100.0 * self._done / self._total if self._total else 100.0  # nothing to convert: done

    def advance(self, episodes: int = 1) -> None:
        """Episodes finished (several at once from a task run that converted several)."""
        first = self._done + 1
        self._done += episodes
        update_progress_artifact(self._id, self._percent(), description=self._text())
        for done in range(first, self._done + 1):  # a bar counts bags, one at a time
            for listener in LISTENERS:
                listener(done, self._total)


def qa_table(report: DatasetReport) -> list[dict[str, Any]]:
    """One row per bag: where it went, QA score and verdict, video fidelity, and why."""
    return [
        {
            "bag": row.name,
            "episode_index": "excluded" if row.episode_index is None else row.episode_index,
            "score": row.score,
            "verdict": row.verdict,
            "frames": row.frames,
            "video PSNR min (dB)": row.video_psnr_min_db,
            "video damaged frames": row.video_damaged_frames,
            "label": row.label,
            "reason": row.reason,
        }
        for row in report.qa
    ]


_LISTED = 200
"""Reused episodes listed by name in the summary artifact (the run record lists all)."""


def _markdown(report: DatasetReport) -> str:
    lines = [
        f"# bagport dataset `{report.root}`",
        "",
        (
            f"- this run: **up to date**: {len(report.reused)} episode(s) reused, nothing written"
            if up_to_date(report)
            else f"- this run: {RunCounts.of(report).text()}"
        ),
        f"- the dataset holds **{report.episodes}** episode(s)",
        f"- frames: {report.frames}, duration: {report.duration_s:.1f} s, size: {report.size_bytes / 1e6:.1f} MB",
        f"- tasks: {', '.join(report.tasks)}",
        f"- videos: {', '.join(report.video_keys) or 'none'}",
    ]
    if report.qa_report:
        lines.append(f"- QA report: `{report.root.rstrip('/')}/{report.qa_report}`")
    if report.reused:
        lines += ["", "## Reused from the staging store (not converted again)", ""]
        lines += [f"- `{uri}`" for uri in report.reused[:_LISTED]]
        if len(report.reused) > _LISTED:
            lines.append(f"- ... and {len(report.reused) - _LISTED} more (the run record lists every one)")
    if report.excluded:
        lines += ["", "## Excluded", ""]
        lines += [f"- `{row.name}` ({row.bag_uri}): {row.reason}" for row in report.excluded]
    return "\n".join(lines)


def publish_run_artifacts(report: DatasetReport) -> None:
    create_table_artifact(qa_table(report), key="bagport-qa", description="QA of every episode of the run")
    create_markdown_artifact(
        _markdown(report), key="bagport-summary", description="The dataset this run wrote"
    )
