"""The conversion flow: plan -> map one task per bag -> reduce into a LeRobot dataset."""

from __future__ import annotations

import os
from typing import Any

from prefect import flow, get_run_logger
from prefect.futures import wait
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, ThreadPoolTaskRunner

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.errors import BagportError
from tasks.episode import convert_episode_task
from tasks.plan import plan_task
from tasks.reduce import reduce_task

__all__ = ["ConversionError", "convert_flow", "run_convert"]


class ConversionError(BagportError):
    """One or more bags failed; nothing was written at the output."""


def _label(uri: str) -> str:
    return uri.rstrip("/").rsplit("/", 1)[-1]


@flow(name="bagport-convert", flow_run_name="convert {config.output}", validate_parameters=True)
def convert_flow(config: ConvertConfig) -> DatasetReport:
    logger = get_run_logger()
    plan = plan_task(config)
    futures = [
        convert_episode_task.submit(request.to_dict(), label=_label(request.bag_uri))
        for request in plan.requests
    ]
    wait(futures)
    staged: list[dict[str, Any]] = []
    failures: list[str] = []
    for request, future in zip(plan.requests, futures, strict=True):
        try:
            staged.append(future.result())
        except BagportError as err:
            failures.append(f"- bags[{request.manifest_entry}] {request.bag_uri}: {err}")
        except Exception as err:  # an unexpected bug: still report which bag, never lose the others
            failures.append(
                f"- bags[{request.manifest_entry}] {request.bag_uri}: unexpected {type(err).__name__}: {err}"
            )
    if failures:
        done = len(staged)
        raise ConversionError(
            f"{len(failures)} of {len(plan.requests)} bag(s) failed; nothing was written at {config.output} "
            f"({done} converted episode(s) are kept in the staging store {config.resolved_staging()}).\n"
            + "\n".join(failures)
        )
    logger.info("all %d episode(s) staged; writing the dataset", len(staged))
    return reduce_task(plan, staged)


def run_convert(config: ConvertConfig) -> DatasetReport:
    """Run the flow with the task runner the config asks for."""
    workers = config.workers or os.cpu_count() or 1
    runner: TaskRunner[Any]
    if config.runner == "process" and workers > 1:
        runner = ProcessPoolTaskRunner(max_workers=workers)
    else:
        runner = ThreadPoolTaskRunner(max_workers=workers)
    # Prefect types task_runner as TaskRunner[PrefectFuture]; both runners are, but not in its stubs.
    result: DatasetReport = convert_flow.with_options(task_runner=runner)(config)  # type: ignore[arg-type]
    return result
