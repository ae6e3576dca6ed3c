"""Merge staged episodes into the LeRobot dataset (the reduce step)."""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger, task
from prefect.client.schemas.objects import State
from prefect.states import Failed

from bagport.dataset import DatasetReport
from bagport.episode.staged import PlannedEpisode
from bagport.errors import BagportError
from bagport.run import EpisodeFailure, RunPlan, reduce_run

__all__ = ["reduce_task"]


@task(name="write-dataset")
def reduce_task(
    plan: RunPlan, staged: list[PlannedEpisode], failures: list[EpisodeFailure]
) -> DatasetReport | State[Any]:
    """Ends Failed with bagport's one-paragraph error as the message when the dataset cannot be written."""
    try:
        report = reduce_run(plan, staged, failures)
    except BagportError as err:
        get_run_logger().error("%s", err)
        return Failed(message=str(err), data=err)  # the error's type decides the CLI's exit code
    logger = get_run_logger()
    logger.info(
        "wrote %d episode(s), %d frames to %s (%d converted now, %d reused from the staging store)",
        report.episodes, report.frames, report.root, report.converted, len(report.reused),
    )  # fmt: skip
    for fmt, output in report.outputs.items():
        logger.info("wrote %s at %s", fmt, output)
    for row in report.excluded:
        logger.warning("excluded %s: %s", row.bag_uri, row.reason)
    return report
