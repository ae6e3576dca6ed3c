"""The reduce as a map on the flow's task runner: select the episodes, then one task per output file (so on
Dask or Ray the remuxing runs on the workers, in parallel, from the shared staging store), then one small
commit task that writes ``meta/`` and publishes.

The write is opened here, in the flow's process (:func:`bagport.dataset.session.open_write`): it holds
the build folder's lock (or the object store's intent record) from the first file to the commit, and
removes whatever was not committed when the block ends.
"""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger
from prefect.client.schemas.objects import State
from prefect.futures import wait
from prefect.states import Failed

from bagport.dataset import DatasetReport
from bagport.dataset.session import open_write
from bagport.episode.staged import PlannedEpisode
from bagport.errors import BagportError
from bagport.run import EpisodeFailure, ReduceStart, RunPlan
from tasks.reduce import commit_task, reduce_task, start_reduce_task, write_file_task

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
    started = start_reduce_task(plan, staged, failures, return_state=True)
    if not started.is_completed():
        return _failed(started, "selecting the episodes")
    start = started.result()
    if isinstance(start, DatasetReport):  # nothing kept: the exclusions are recorded
        return start
    assert isinstance(start, ReduceStart)
    config = plan.config
    try:
        with open_write(
            start.kept, config.output, limits=start.limits, overwrite=config.overwrite, append=config.append
        ) as session:
            get_run_logger().info("writing %d output file(s)", len(session.plan.files))
            futures = [
                write_file_task.submit(session.plan, item, session.build) for item in session.plan.files
            ]
            wait(futures)
            for future in futures:
                if not future.state.is_completed():
                    return _failed(future.state, "writing an output file")
            written = [future.result() for future in futures]
            committed = commit_task(plan, staged, failures, start, session, written, return_state=True)
            if not committed.is_completed():
                return _failed(committed, "committing the dataset")
            report: DatasetReport = committed.result()  # type: ignore[assignment] # completed: a report
    except BagportError as err:  # opening the write: a dataset that may not be replaced, features that differ
        get_run_logger().error("%s", err)
        return Failed(message=str(err), data=err)
    return report
