"""The reduce step: staged episodes in, one LeRobot v3.0 dataset out, published atomically.

Three steps, each a library call a task runner can place anywhere (:mod:`bagport.dataset.session`,
:mod:`bagport.dataset.files`, :mod:`bagport.dataset.commit`): open the write (repair, plan the output
files, hold a build location), write each planned file, then commit ``meta/`` and publish.
:func:`write_dataset` runs them in this process, one file after another; :func:`dataset_written` too,
and holds the output (its build folder's lock, or the object store's intent record) while its block runs.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from bagport.dataset.commit import DatasetReport, commit_write
from bagport.dataset.files import write_planned_file
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.session import open_write
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

__all__ = ["DatasetReport", "dataset_written", "write_dataset"]


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
) -> DatasetReport:
    """Write the dataset at ``output`` (the dataset root).

    Whatever a killed run left at ``output`` is repaired first (:mod:`bagport.dataset.repair`). A new
    dataset is built beside a local ``output`` and put in place by one atomic exchange
    (:mod:`bagport.dataset.publish`); on an object store its files are uploaded under an intent record
    and committed (:mod:`bagport.dataset.remote`). With ``append``, the episodes are added to the
    dataset at ``output`` (created if missing) as new files: old data and video files never change,
    and are never read. ``expect_episodes``: see :func:`~bagport.dataset.session.open_write`.
    """
    with dataset_written(
        summaries,
        output,
        robot_type=robot_type,
        limits=limits,
        run_record=run_record,
        overwrite=overwrite,
        qa=qa,
        qa_config=qa_config,
        append=append,
        expect_episodes=expect_episodes,
    ) as report:
        return report


@contextmanager
def dataset_written(
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
) -> Iterator[DatasetReport]:
    """:func:`write_dataset`, whose report the block gets once the dataset is committed, with the output
    still held: another run's recovery or append at ``output`` waits for (or refuses) a live write until
    the block ends. What the block does after a commit (the other formats from the same staged episodes)
    is then never raced by an append that removes those staged episodes."""
    with open_write(
        summaries, output, limits=limits, overwrite=overwrite, append=append, expect_episodes=expect_episodes
    ) as session:
        written = [write_planned_file(session.plan, item, session.build) for item in session.plan.files]
        yield commit_write(
            session,
            summaries,
            written,
            robot_type=robot_type,
            run_record=run_record,
            qa=qa,
            qa_config=qa_config,
        )
