"""Convert one bag into a staged episode (the map step)."""

from __future__ import annotations

import time
from typing import Any

from prefect import Task, get_run_logger, task
from prefect.client.schemas.objects import State, TaskRun
from prefect.states import Failed

from bagport.episode import convert_episode
from bagport.errors import BagportError, TransientError
from bagport.request import EpisodeOutcome, EpisodeRequest
from bagport.staging import EpisodeSummary

__all__ = ["BATCH_RETRY_DELAYS_S", "convert_batch_task", "convert_episode_task", "retry_only_transient"]

BATCH_RETRY_DELAYS_S = (2, 10)
"""A bag of a batch is retried on a transient I/O error, after these delays (as a task run is)."""


def retry_only_transient(_task: Task[Any, Any], _run: TaskRun, state: State[Any]) -> bool:
    """Retry network hiccups; a bad bag fails fast."""
    try:
        state.result()
    except TransientError:
        return True
    except Exception:  # any other failure is final
        return False
    return False


@task(
    name="convert-episode",
    task_run_name="convert {label}",
    retries=2,
    retry_delay_seconds=[2, 10],
    retry_condition_fn=retry_only_transient,
    tags=["bagport", "episode"],
)
def convert_episode_task(request: EpisodeRequest, label: str) -> EpisodeOutcome | State[Any]:
    """Returns the staged episode's folder URI and a small summary, never arrays.

    A bad bag ends the task run in a Failed state whose message is bagport's one-paragraph
    error (no traceback in the logs); transient I/O errors raise, so Prefect retries them.
    """
    try:
        summary = convert_episode(request)
    except TransientError:
        raise
    except BagportError as err:
        get_run_logger().error("%s: %s", label, err)
        return Failed(message=str(err))
    return _staged(label, summary)


def _staged(label: str, summary: EpisodeSummary) -> EpisodeOutcome:
    """Log a staged episode under its bag's label; the small result the flow gets."""
    read = summary.bag_read
    get_run_logger().info(
        "%s: %d frames staged at %s (bag %s, %s bytes read)",
        label, summary.frames, summary.dir_uri, read.get("access"), read.get("bytes_read"),
    )  # fmt: skip
    for warning in read.get("warnings", ()):
        get_run_logger().warning("%s: %s", label, warning)
    return EpisodeOutcome(summary.episode_id, summary.dir_uri, summary.frames, summary.qa.get("verdict"))


@task(
    name="convert-episodes",
    task_run_name="convert {label}",
    tags=["bagport", "episode"],
)
def convert_batch_task(
    requests: list[EpisodeRequest],
    labels: list[str],
    label: str,  # noqa: ARG001 - names the task run
) -> list[EpisodeOutcome]:
    """Convert small episodes one after another in one task run (Prefect's cost per task run is
    larger than such an episode's). Each bag keeps its own log lines (prefixed by its label) and its
    own outcome: a staged episode, or bagport's one-paragraph error; a
    transient I/O error is retried for that bag alone (:data:`BATCH_RETRY_DELAYS_S`)."""
    return [_convert_retrying(request, name) for request, name in zip(requests, labels, strict=True)]


def _convert_retrying(request: EpisodeRequest, label: str) -> EpisodeOutcome:
    logger = get_run_logger()
    for delay_s in (*BATCH_RETRY_DELAYS_S, None):
        try:
            return _staged(label, convert_episode(request))
        except TransientError as err:
            if delay_s is None:
                logger.error("%s: %s", label, err)
                return EpisodeOutcome(request.episode_id, error=str(err), transient=True)
            logger.warning("%s: %s; retrying in %d s", label, err, delay_s)
            time.sleep(delay_s)
        except BagportError as err:
            logger.error("%s: %s", label, err)
            return EpisodeOutcome(request.episode_id, error=str(err))
    raise AssertionError("unreachable: the last attempt returns")
