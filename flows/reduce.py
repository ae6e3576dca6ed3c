"""The reduce as a map on the flow's task runner: select the episodes, then one task per output file (so on
Dask or Ray the remuxing runs on the workers, in parallel, from the shared staging store), then one small
commit step that writes ``meta/`` and publishes.

Selecting the episodes (:func:`bagport.reduce.start_reduce`), opening the write
(:func:`bagport.dataset.session.open_write`) and the commit (:func:`bagport.dataset.commit.commit_write`)
run here, in the flow's process, as library calls: the write holds the build folder's lock (or the object
store's intent record) from the first file to the commit and removes whatever was not committed when the
block ends, and what they pass each other (every kept episode's summary and QA, the run record) stays in
this process. Only the file writers' small typed values cross the task boundary.
"""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger
from prefect.client.schemas.objects import State
from prefect.futures import wait
from prefect.states import Failed

from bagport.dataset import DatasetReport
from bagport.dataset.commit import commit_write
from bagport.dataset.files import WrittenFile
from bagport.dataset.session import open_write
from bagport.episode.staged import PlannedEpisode
from bagport.errors import BagportError
from bagport.reduce import commit_reduce, start_reduce
from bagport.run import EpisodeFailure, RunPlan
from tasks.reduce import failed_with, log_report, reduce_task, write_file_task

__all__ = ["reduce_dataset"]


def _failed(state: State[Any], what: str) -> State[Any]:
    error = state.result(raise_on_failure=False)
    return Failed(
        message=state.message or f"{what} failed", data=error if isinstance(error, BagportError) else None
    )


def reduce_dataset(
    plan: RunPlan, staged: list[PlannedEpisode], failures: list[EpisodeFailure]
) -> DatasetReport | State[Any]:
    """The dataset's report, or the Failed state whose data is bagport's error (its type: the exit code)."""
    if "lerobot" not in plan.config.formats:  # the other formats write in one task
        reduced = reduce_task(plan, staged, failures, return_state=True)
        return reduced.result() if reduced.is_completed() else _failed(reduced, "writing the dataset")
    config = plan.config
    try:
        start = start_reduce(plan, staged, failures)
        if isinstance(start, DatasetReport):  # nothing kept: the exclusions are recorded
            return start
        with open_write(
            start.kept,
            config.output,
            limits=start.limits,
            overwrite=config.overwrite,
            append=config.append,
            repaired=True,  # by plan_run, at the start of this run: recovery runs once per run
        ) as session:
            get_run_logger().info("writing %d output file(s)", len(session.plan.files))
            futures = [
                write_file_task.submit(session.plan, item, session.build) for item in session.plan.files
            ]
            wait(futures)
            for future in futures:
                if not future.state.is_completed():
                    return _failed(future.state, "writing an output file")
            written: list[WrittenFile] = [future.result() for future in futures]  # type: ignore[misc] # completed
            lerobot = commit_write(
                session,
                start.kept,
                written,
                robot_type=plan.contract.robot_type,
                run_record=start.record,
                qa=start.entries,
                qa_config=plan.qa.model_dump(mode="json"),
            )
            report = commit_reduce(plan, staged, failures, start, lerobot)
    except BagportError as err:  # a staged episode gone, a dataset that may not be replaced, the commit
        return failed_with(err)
    log_report(report)
    return report
