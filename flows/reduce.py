"""The reduce as a map on the flow's task runner: select the episodes, then one task per output file (so on
Dask or Ray the remuxing runs on the workers, in parallel, from the shared staging store), then one small
commit step that writes ``meta/`` and publishes.

Selecting the episodes (:func:`bagport.reduce.start_reduce`), opening the write
(:func:`bagport.dataset.session.open_write`) and the commit (:func:`bagport.dataset.commit.commit_write`)
run here, in the flow's process, as library calls: the write holds the build folder's lock (or the object
store's intent record) from the first file to the commit and removes whatever was not committed when the
block ends, and what they pass each other (every kept episode's summary and QA, the run record) stays in
this process. Only the file writers' small typed values cross the task boundary.

Where the file tasks run (:func:`_file_writers`): on Dask and Ray, the cluster's workers; with the local
process pool, threads of the flow's process. A file task copies staged bytes (a remux, no decoding; a
parquet concatenation), so a fresh pool worker's start-up (importing Prefect and bagport, 3-8 s on 2 cores)
costs more than the writing itself, and a run with every episode staged has started no worker yet.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from prefect import get_run_logger
from prefect.client.schemas.objects import State
from prefect.context import FlowRunContext
from prefect.futures import PrefectFuture, wait
from prefect.states import Failed
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, ThreadPoolTaskRunner

from bagport.dataset import DatasetReport
from bagport.dataset.commit import commit_write
from bagport.dataset.files import FilePlan, WrittenFile
from bagport.dataset.free_memory import release_unused_memory
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


@contextmanager
def _file_writers(workers: int) -> Iterator[TaskRunner[Any] | None]:
    """``workers`` threads of this process when the flow runs on the local process pool, else ``None``:
    the flow's own runner (Dask, Ray, threads)."""
    context = FlowRunContext.get()
    if context is None or not isinstance(context.task_runner, ProcessPoolTaskRunner):
        yield None
        return
    threads: ThreadPoolTaskRunner[Any]
    with ThreadPoolTaskRunner(max_workers=workers) as threads:
        yield threads


def _submit_writes(threads: TaskRunner[Any] | None, plan: FilePlan, build: str) -> list[PrefectFuture[Any]]:
    if threads is None:
        return [write_file_task.submit(plan, item, build) for item in plan.files]
    return [
        threads.submit(write_file_task, parameters={"plan": plan, "item": item, "build": build})
        for item in plan.files
    ]


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
            expect_episodes=plan.dataset_episodes,  # another append since this plan: refused
        ) as session:
            get_run_logger().info("writing %d output file(s)", len(session.plan.files))
            with _file_writers(config.resolved_workers()) as threads:
                futures = _submit_writes(threads, session.plan, session.build)
                wait(futures)
            release_unused_memory()  # what the file writers (threads here, with the local pool) freed
            for future in futures:
                if not future.state.is_completed():
                    return _failed(future.state, "writing an output file")
            written: list[WrittenFile] = [future.result() for future in futures]
            lerobot = commit_write(
                session,
                start.kept,
                written,
                robot_type=plan.contract.robot_type,
                run_record=start.record,
                qa=start.entries,
                qa_config=plan.qa.model_dump(mode="json"),
            )
            report = commit_reduce(plan, staged, start, lerobot)
    except BagportError as err:  # a staged episode gone, a dataset that may not be replaced, the commit
        return failed_with(err)
    log_report(report)
    return report
