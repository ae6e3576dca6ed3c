"""Merge staged episodes into the LeRobot dataset (the reduce step): start, one task per output file, commit."""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger, task
from prefect.client.schemas.objects import State
from prefect.states import Failed

from bagport.dataset import DatasetReport
from bagport.dataset.commit import commit_write
from bagport.dataset.files import FilePlan, PlannedFile, WrittenFile, write_planned_file
from bagport.dataset.session import WriteSession
from bagport.episode.staged import PlannedEpisode
from bagport.errors import BagportError
from bagport.run import EpisodeFailure, ReduceStart, RunPlan, commit_reduce, reduce_run, start_reduce

__all__ = ["commit_task", "reduce_task", "start_reduce_task", "write_file_task"]


def _failed(err: BagportError) -> State[Any]:
    get_run_logger().error("%s", err)
    return Failed(message=str(err), data=err)  # the error's type decides the CLI's exit code


def _log(report: DatasetReport) -> None:
    logger = get_run_logger()
    logger.info(
        "wrote %d episode(s), %d frames to %s (%d converted now, %d reused from the staging store)",
        report.episodes, report.frames, report.root, report.converted, len(report.reused),
    )  # fmt: skip
    for fmt, output in report.outputs.items():
        logger.info("wrote %s at %s", fmt, output)
    for row in report.excluded:
        logger.warning("excluded %s: %s", row["bag_uri"], row["reason"])


@task(name="write-dataset")
def reduce_task(
    plan: RunPlan, staged: list[PlannedEpisode], failures: list[EpisodeFailure]
) -> DatasetReport | State[Any]:
    """The whole reduce in one task (formats other than LeRobot only). Ends Failed with bagport's
    one-paragraph error as the message when the dataset cannot be written."""
    try:
        report = reduce_run(plan, staged, failures)
    except BagportError as err:
        return _failed(err)
    _log(report)
    return report


@task(name="select-episodes")
def start_reduce_task(
    plan: RunPlan, staged: list[PlannedEpisode], failures: list[EpisodeFailure]
) -> ReduceStart | DatasetReport | State[Any]:
    """The kept episodes and their QA (a report when none is kept: nothing to write)."""
    try:
        return start_reduce(plan, staged, failures)
    except BagportError as err:
        return _failed(err)


@task(name="write-file", task_run_name="write {item.name}", tags=["bagport", "write-file"])
def write_file_task(plan: FilePlan, item: PlannedFile, build: str) -> WrittenFile | State[Any]:
    """One output file (data or one camera's video file) from the staging store into the build location."""
    try:
        return write_planned_file(plan, item, build)
    except BagportError as err:
        return _failed(err)


@task(name="commit-dataset")
def commit_task(
    plan: RunPlan,
    staged: list[PlannedEpisode],
    failures: list[EpisodeFailure],
    start: ReduceStart,
    session: WriteSession,
    written: list[WrittenFile],
) -> DatasetReport | State[Any]:
    """``meta/`` from the file writers' results, the publish, then the other formats and the clean-up."""
    try:
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
    except BagportError as err:
        return _failed(err)
    _log(report)
    return report
