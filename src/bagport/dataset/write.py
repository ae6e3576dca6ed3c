"""The reduce step: staged episodes in, one LeRobot v3.0 dataset out, published atomically.

Three steps, each a library call a task runner can place anywhere (:mod:`bagport.dataset.session`,
:mod:`bagport.dataset.files`, :mod:`bagport.dataset.commit`): open the write (repair, plan the output
files, hold a build location), write each planned file, then commit ``meta/`` and publish.
:func:`write_dataset` runs them in this process, one file after another.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from bagport.dataset.commit import DatasetReport, commit_write
from bagport.dataset.files import write_planned_file
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.session import open_write
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

__all__ = ["DatasetReport", "write_dataset"]


def write_dataset(
    summaries: Sequence[EpisodeSummary],
    output: str,
    *,
    robot_type: str,
    limits: DatasetLimits | None = None,
    run_record: dict[str, Any] | None = None,
    overwrite: bool = False,
    qa: Sequence[QAEntry] = (),
    qa_config: dict[str, Any] | None = None,
    append: bool = False,
    expect_episodes: int | None = None,
    then: Callable[[DatasetReport], DatasetReport] | None = None,
) -> DatasetReport:
    """Write the dataset at ``output`` (the dataset root).

    Whatever a killed run left at ``output`` is repaired first (:mod:`bagport.dataset.repair`). A new
    dataset is built beside a local ``output`` and put in place by one atomic exchange
    (:mod:`bagport.dataset.publish`); on an object store its files are uploaded under an intent record
    and committed (:mod:`bagport.dataset.remote`). With ``append``, the episodes are added to the
    dataset at ``output`` (created if missing) as new files: old data and video files never change,
    and are never read. ``expect_episodes``: see :func:`~bagport.dataset.session.open_write`.
    ``then``: called with the committed dataset's report while the output is still held (another run's
    recovery or append at ``output`` refuses a live write), and its result returned: what a run does after
    its commit from the same staged episodes (the other formats) is never raced by an append that removes
    them as a killed run's leftovers.
    """
    with open_write(
        summaries, output, limits=limits, overwrite=overwrite, append=append, expect_episodes=expect_episodes
    ) as session:
        written = [write_planned_file(session.plan, item, session.build) for item in session.plan.files]
        report = commit_write(
            session,
            summaries,
            written,
            robot_type=robot_type,
            run_record=run_record,
            qa=qa,
            qa_config=qa_config,
        )
        return report if then is None else then(report)
