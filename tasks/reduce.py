"""Merge staged episodes into the LeRobot dataset (the reduce step): one task per output file (the flow
selects the episodes and commits, ``flows/reduce.py``), or the whole reduce in one task for other formats."""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger, task
from prefect.client.schemas.objects import State
from prefect.states import Failed

from bagport.dataset import DatasetReport
from bagport.dataset.files import FilePlan, PlannedFile, WrittenFile, write_planned_file
from bagport.episode.staged import PlannedEpisode
from bagport.errors import BagportError
from bagport.reduce import reduce_run
from bagport.run import EpisodeFailure, RunPlan

__all__ = ["failed_with", "log_report", "reduce_task", "write_file_task"]


def failed_with(err: BagportError) -> State[Any]:
    """The Failed state carrying bagport's error (logged): its type decides the CLI's exit code. Without
    its traceback: the state outlives the run, and the traceback's frames would keep what the reduce held
    (the stats' sketches) alive to the interpreter's exit, where their library printed ~600 lines of
    "leaked instances" under the one-paragraph error."""
    get_run_logger().error("%s", err)
    return Failed(message=str(err), data=err.with_traceback(None))


def log_report(report: DatasetReport) -> None:
    """What the run wrote, and each excluded bag, in the run's log."""
    logger = get_run_logger()
    logger.info(
        "wrote %d episode(s), %d frames to %s (%d converted now, %d reused from the staging store)",
        report.episodes, report.frames, report.root, report.converted, len(report.reused),
    )  # fmt: skip
    for fmt, output in report.outputs.items():
        logger.info("wrote %s at %s", fmt, output)
    for row in report.excluded:
        logger.warning("excluded %s: %s", row.bag_uri, row.reason)


@task(name="write-dataset")
def reduce_task(
    plan: RunPlan, staged: list[PlannedEpisode], failures: list[EpisodeFailure]
) -> DatasetReport | State[Any]:
    """The whole reduce in one task (formats other than LeRobot only). Ends Failed with bagport's
    one-paragraph error as the message when the dataset cannot be written."""
    try:
        report = reduce_run(plan, staged, failures)
    except BagportError as err:
        return failed_with(err)
    log_report(report)
    return report


@task(name="write-file", task_run_name="write {item.name}", tags=["bagport", "write-file"])
def write_file_task(plan: FilePlan, item: PlannedFile, build: str) -> WrittenFile | State[Any]:
    """One output file (data or one camera's video file) from the staging store into the build location."""
    try:
        return write_planned_file(plan, item, build)
    except BagportError as err:
        return failed_with(err)
