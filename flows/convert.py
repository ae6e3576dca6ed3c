"""The conversion flow: plan -> map one task per bag -> reduce into a LeRobot dataset."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

# Prefect imports these at a flow's first call, once its API answers (Flow.__call__ the task
# visualisation, serialize_parameters FastAPI's encoder: 0.07-0.2 s): imported with this module, so a
# CLI run imports them while its temporary server boots instead of after
import fastapi.encoders  # noqa: F401
import prefect.utilities.visualization  # noqa: F401
from prefect import flow, get_run_logger
from prefect.client.schemas.objects import State
from prefect.futures import PrefectFuture, as_completed
from prefect.states import Failed
from prefect.task_runners import TaskRunner, ThreadPoolTaskRunner

from bagport.bags import source_stamp
from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.episode import EpisodeRequest
from bagport.episode.staged import PlannedEpisode, split_staged
from bagport.errors import BagportError, QualityError
from bagport.reduce import finish_nothing_new, finish_up_to_date
from bagport.request import EpisodeOutcome
from bagport.run import EpisodeFailure, RunPlan, plan_run
from bagport.segment import SegmentedBag, segments_bags
from flows import forkserver
from flows.artifacts import Progress, publish_run_artifacts
from flows.cancel import cancel_unfinished
from flows.finished import Finished, not_the_bags_fault
from flows.reduce import reduce_dataset
from flows.run_story import completed_state
from flows.runners import (
    RayMissingError,
    ServerDownError,
    WarmProcessPoolTaskRunner,
    dask_runner,
    prefect_api,
    ray_runner,
)
from tasks.episode import convert_batch_task, convert_episode_task
from tasks.plan import plan_task
from tasks.segment import segment_bag_task

__all__ = [
    "ConversionError",
    "FlowFailedError",
    "RayMissingError",
    "ServerDownError",
    "convert_flow",
    "run_config",
    "run_convert",
]


class ConversionError(QualityError):
    """``--fail-fast``: a bag failed, the run stopped and nothing was written (exit code 1, by type)."""


class FlowFailedError(BagportError):
    """The conversion flow ended without a result and without one of bagport's errors (crashed or
    cancelled): its state's message says why."""


def _label(uri: str) -> str:
    return uri.rstrip("/").rsplit("/", 1)[-1]


@flow(name="bagport-convert", flow_run_name="convert {config.output}", validate_parameters=True)
def convert_flow(config: ConvertConfig) -> DatasetReport | State[Any]:
    logger = get_run_logger()
    plan = _checked_plan(config) or plan_task(config)
    if plan.staging_removed:
        logger.info("%s: %s", plan.staging_note(), ", ".join(plan.staging_removed))
    for overlap in plan.overlaps:
        logger.warning("%s", overlap.note())
    finished = _nothing_to_convert(plan)
    if finished is not None:
        return finished
    episodes = _Episodes(plan)
    if plan.reused:
        logger.info(
            "%d episode(s) staged already with the same key: not converted again; %d bag(s) to convert",
            len(plan.reused), len(plan.requests),
        )  # fmt: skip
    failures: list[EpisodeFailure] = []  # bags that could not even be split into episodes, so far
    stopped = _submit_episodes(plan, episodes, failures) or _wait_for_episodes(plan, episodes)
    if stopped is not None:  # --fail-fast
        return stopped
    unsegmented = len(failures)
    staged = list(episodes.reused)
    for done in episodes.in_plan_order():
        if done.error is None:
            staged.append(PlannedEpisode.of(done.request))
        else:  # bagport's one-paragraph error (a bad bag's task ends Failed with it as its message)
            failures.append(EpisodeFailure.of(done.request, done.error, retryable=done.retryable))
    if failures:
        logger.warning(
            "%d of %d episode(s) failed; the QA policy (on_fail: %s) decides what happens to the run:\n%s",
            len(failures),
            episodes.count + unsegmented,
            plan.qa.on_fail,
            "\n".join(f"- bags[{f.manifest_entry}] {f.bag_uri}: {f.error}" for f in failures),
        )
    logger.info("%d episode(s) staged; writing the dataset", len(staged))
    # a task per output file, then the commit (flows/reduce.py); an error is the state's data (its exit code)
    report = reduce_dataset(plan, staged, failures)
    if not isinstance(report, DatasetReport):
        return report
    publish_run_artifacts(report)
    return completed_state(report)  # "Completed with exclusions" in run lists when bags were left out


def _nothing_to_convert(plan: RunPlan) -> DatasetReport | None:
    """The report of a run with nothing to convert (up to date, or nothing new to append); else ``None``."""
    logger, config = get_run_logger(), plan.config
    if plan.up_to_date:  # the same write key as the dataset at the output: nothing to convert or write
        logger.info(
            "up to date: %d episode(s) reused, nothing to write at %s", len(plan.reused), config.output
        )
        Progress(0, len(plan.reused))
        unchanged = finish_up_to_date(plan)
        publish_run_artifacts(unchanged)
        return unchanged
    if not plan.requests and not plan.reused:  # an append or ingestion run with nothing new
        logger.info(
            "no new bag: every bag of %s is in %s already, or was left out of it and is unchanged",
            config.manifest or config.bags_glob, config.output,
        )  # fmt: skip
        return finish_nothing_new(plan)
    return None


def _submit_episodes(plan: RunPlan, episodes: _Episodes, failures: list[EpisodeFailure]) -> State[Any] | None:
    """Submit every bag's episodes: at once, or each bag's as soon as it is split (the others meanwhile). A bag
    that cannot be split goes to ``failures``; with ``--fail-fast`` it stops the run (its Failed state)."""
    if not segments_bags(plan.contract):
        episodes.submit_bags(plan.requests)
        return None
    config = plan.config
    segmenting = [_submit_segment(plan, request) for request in plan.requests]
    position = {id(f): i for i, f in enumerate(segmenting)}
    for done in as_completed(segmenting):
        bag = plan.requests[position[id(done)]]
        found, failure = _segments_of(bag, done)
        episodes.submit(position[id(done)], found)
        if failure is None:
            continue
        failures.append(failure)
        if config.fail_fast:
            unfinished = cancel_unfinished(segmenting) + cancel_unfinished(episodes.futures)
            return _stopped(
                f"bags[{failure.manifest_entry}] {failure.bag_uri} could not be split into episodes "
                f"({failure.error}) and --fail-fast is set: the run stopped ({unfinished} task(s) were not "
                f"finished) and nothing was written at {config.output}."
            )
    return None


def _wait_for_episodes(plan: RunPlan, episodes: _Episodes) -> State[Any] | None:
    """Follow the episodes as they finish; with ``--fail-fast`` a failure (or a QA fail under ``fail_run``)
    cancels the rest and stops the run (its Failed state)."""
    config = plan.config
    for done in as_completed(episodes.futures):
        done.wait()  # records the final state on the future; `.state` would otherwise ask the API, which lags
        outcomes = episodes.outcomes(done)
        episodes.progress.advance(len(outcomes))
        stop = _fail_fast_reason(plan, outcomes) if config.fail_fast else None
        if stop is not None:
            unfinished = episodes.cancel_unfinished()
            return _stopped(
                f"{stop} and --fail-fast is set: the run stopped ({unfinished} of {episodes.count} "
                f"episode(s) were not finished) and nothing was written at {config.output}. Finished episodes "
                f"stay in the staging store {config.resolved_staging()} and a re-run reuses them."
            )
    return None


def _stopped(what: str) -> State[Any]:
    """The Failed state of a run ``--fail-fast`` stopped (``what`` happened), logged with the fix."""
    message = (
        f"{what} Fix: correct or remove that bag, or leave out --fail-fast to convert the others and "
        "list the failures."
    )
    get_run_logger().error("%s", message)
    return Failed(message=message, data=ConversionError(message))


class _Episodes:
    """The conversion tasks submitted so far, with their requests and place in the plan.

    Small episodes of many go several to a task run (:func:`batch_size`): Prefect's cost per task
    run (creating it, state changes, dispatch to the pool) is larger than a one-second episode's
    conversion. Each bag still logs under its own name, counts on the progress bar and fails alone.
    """

    def __init__(self, plan: RunPlan) -> None:
        self._plan = plan
        self.reused = list(plan.reused)
        self.progress = Progress(0, len(self.reused))
        self.futures: list[PrefectFuture[Any]] = []
        self._batches: list[list[tuple[tuple[int, int], EpisodeRequest]]] = []
        self._index: dict[int, int] = {}

    @property
    def count(self) -> int:
        """Episodes submitted."""
        return sum(len(batch) for batch in self._batches)

    def submit(self, bag_position: int, requests: list[EpisodeRequest]) -> None:
        """The episodes of the bag at ``bag_position`` in the plan, in their order inside it; those
        staged already with a matching key are reused, not submitted."""
        split = split_staged(requests, self._plan.staged_ids, source_stamp)
        self.reused += split.reused
        self.progress.add(len(split.todo), reused=len(split.reused))
        todo = {r.episode_id for r in split.todo}
        for i, request in enumerate(requests):
            if request.episode_id in todo:
                self._submit([((bag_position, i), request)])

    def submit_bags(self, requests: tuple[EpisodeRequest, ...]) -> None:
        """One episode per bag, in plan order, :func:`batch_size` bags to a task run."""
        self.progress.add(len(requests))
        size = batch_size(len(requests), self._plan.config.resolved_workers())
        for start in range(0, len(requests), size):
            self._submit([((i, 0), requests[i]) for i in range(start, min(start + size, len(requests)))])

    def _submit(self, batch: list[tuple[tuple[int, int], EpisodeRequest]]) -> None:
        requests = [request for _, request in batch]
        future: PrefectFuture[Any]
        if len(requests) == 1:
            one = convert_episode_task.with_options(
                tags=_bag_tags(convert_episode_task.tags, self._plan, requests)
            )
            future = one.submit(requests[0], label=requests[0].name)
        else:
            many = convert_batch_task.with_options(
                tags=_bag_tags(convert_batch_task.tags, self._plan, requests)
            )
            future = many.submit(
                requests,
                labels=[r.name for r in requests],
                label=f"{requests[0].name} +{len(requests) - 1}",
            )
        self._index[id(future)] = len(self.futures)
        self.futures.append(future)
        self._batches.append(batch)

    def outcomes(self, future: PrefectFuture[Any]) -> list[Finished]:
        """How each episode of a finished task run ended."""
        batch = [request for _, request in self._batches[self._index[id(future)]]]
        state = future.state
        if not state.is_completed():
            error, retryable = state.message or str(state.name), not_the_bags_fault(state)
            return [Finished(r, error, None, retryable) for r in batch]
        result = future.result()
        items: list[EpisodeOutcome] = result if isinstance(result, list) else [result]
        return [Finished(r, i.error, i.qa_verdict, i.transient) for r, i in zip(batch, items, strict=True)]

    def in_plan_order(self) -> list[Finished]:
        """Episodes in manifest order, then in their order inside the bag (not in finishing order)."""
        rows = [
            (place, done)
            for future, batch in zip(self.futures, self._batches, strict=True)
            for (place, _), done in zip(batch, self.outcomes(future), strict=True)
        ]
        rows.sort(key=lambda row: row[0])
        return [done for _, done in rows]

    def cancel_unfinished(self) -> int:
        """Cancel the task runs not finished yet; how many episodes they held."""
        return sum(
            len(batch) * cancel_unfinished([future])
            for future, batch in zip(self.futures, self._batches, strict=True)
        )


MAX_BATCH = 32
"""At most this many episodes in one task run."""
TASK_RUNS_PER_WORKER = 4
"""At least this many task runs per worker, so the workers finish together (the last task runs are
the pool's tail; a task run of 32 one-second bags takes about 3 s)."""


def batch_size(episodes: int, workers: int) -> int:
    """Episodes per task run: one while there are fewer than 8 per worker (every bag its own task run,
    the pool balanced), then more, up to :data:`MAX_BATCH`, keeping at least
    :data:`TASK_RUNS_PER_WORKER` task runs per worker. Each task run costs Prefect about 0.1-0.2 s
    of a worker (BENCHMARKS.md, W3)."""
    return max(1, min(MAX_BATCH, episodes // (TASK_RUNS_PER_WORKER * workers)))


def _submit_segment(plan: RunPlan, request: EpisodeRequest) -> PrefectFuture[Any]:
    task = segment_bag_task.with_options(tags=_bag_tags(segment_bag_task.tags, plan, [request]))
    return task.submit(request, label=_label(request.bag_uri))


def _bag_tags(task_tags: set[str], plan: RunPlan, requests: Sequence[EpisodeRequest]) -> set[str]:
    """Tags find a bag's task run in the UI in one click (filter by tag bag:<name> or robot:<type>).

    Set on the task itself, not with ``prefect.tags``: the process runner captures the tag context
    once, at its first submit, and every task run would carry the first bag's tag.
    """
    return {*task_tags, f"robot:{plan.contract.robot_type}", *(f"bag:{_label(r.bag_uri)}" for r in requests)}


def _segments_of(
    request: EpisodeRequest, future: PrefectFuture[Any]
) -> tuple[list[EpisodeRequest], EpisodeFailure | None]:
    """A finished segmentation's episode requests, or why the bag gave none."""
    future.wait()
    state = future.state
    if not state.is_completed():
        error, retryable = state.message or str(state.name), not_the_bags_fault(state)
        return [], EpisodeFailure.of(request, error, retryable=retryable)
    found = future.result()
    assert isinstance(found, SegmentedBag)  # completed: the task returned the bag's episodes
    if not found.requests:
        return [], EpisodeFailure.of(request, found.none_found())
    return list(found.requests), None


def _fail_fast_reason(plan: RunPlan, outcomes: list[Finished]) -> str | None:
    """Why ``--fail-fast`` stops the run after these episodes: a conversion failed, or one failed QA
    under ``fail_run`` (the run fails anyway); ``None`` to go on."""
    for request, error, verdict, _ in outcomes:
        where = f"bags[{request.manifest_entry}] {request.bag_uri} {QualityError.MARKER}"
        if error is not None:
            return f"{where} ({error})"
        if plan.qa.on_fail == "fail_run" and verdict == "fail":
            return f"{where} (QA verdict fail, on_fail is 'fail_run')"
    return None


def run_config(config: ConvertConfig) -> DatasetReport:
    """Run the conversion flow (or subflow, inside a deployment's flow) with the config's task runner."""
    workers = config.resolved_workers()
    runner: TaskRunner[Any]
    if config.runner == "dask":
        runner = dask_runner(config, workers)
    elif config.runner == "ray":
        runner = ray_runner(config, workers)
    elif config.on_local_pool():
        runner = WarmProcessPoolTaskRunner(max_workers=workers)
    else:
        runner = ThreadPoolTaskRunner(max_workers=workers)
    # Prefect types task_runner as TaskRunner[PrefectFuture]; every runner is, but not in its stubs.
    flow_with_runner = convert_flow.with_options(task_runner=runner)  # type: ignore[arg-type]
    state = flow_with_runner(config, return_state=True)
    if not state.is_completed():
        # bagport's own errors arrive typed, as the state's data; anything else is a bug or a crash
        error = state.result(raise_on_failure=False)
        if isinstance(error, BagportError):
            raise error
        raise FlowFailedError(state.message or f"the conversion flow ended {state.name}")
    result: DatasetReport = state.result()  # type: ignore[assignment] # completed: a report
    return result


_CHECKED: list[RunPlan] = []
"""The plan :func:`run_convert` made before Prefect started, for the flow it then runs in this process
(planned once per run: the listing of the staging store and the bags' stamps are not repeated)."""


def _checked_plan(config: ConvertConfig) -> RunPlan | None:
    """The plan checked before the flow started for this config, taken once; ``None`` if none."""
    plan = _CHECKED.pop() if _CHECKED else None
    if plan is None or plan.config != config:
        return None
    get_run_logger().info(
        "%d bag(s) to convert, %d episode(s) staged already, from %s, contract %s (%s, %d fps)",
        len(plan.requests), len(plan.reused), config.manifest or config.bags_glob, config.contract,
        plan.contract.robot_type, plan.contract.fps,
    )  # fmt: skip
    return plan


def run_convert(config: ConvertConfig, plan: RunPlan | None = None) -> DatasetReport:
    """The CLI's entry: plan (and so check the inputs) before Prefect starts, unless given the plan,
    then run against the configured API (or one temporary local server) with that plan."""
    # bad manifests, contracts and outputs fail here, before Prefect starts
    _CHECKED[:] = [plan if plan is not None else plan_run(config)]
    # with nothing to convert (every episode staged already) no worker starts: no forkserver either
    warm = config.on_local_pool() and bool(_CHECKED[0].requests)
    if warm:
        forkserver.start()  # the workers' imports run now, while the temporary Prefect server boots
    stopping: threading.Thread | None = None
    try:
        with prefect_api():
            try:
                return run_config(config)
            finally:
                if warm:  # its workers ended with the flow's pool: it exits while the server stops
                    stopping = forkserver.stop_in_background()
    finally:
        _CHECKED.clear()
        if stopping is not None:
            stopping.join()
        elif warm:  # no flow ran (its API could not be reached): the forkserver is not left behind
            forkserver.stop()
