"""Convert one bag into a staged episode (the map step)."""

from __future__ import annotations

from typing import Any

from prefect import Task, get_run_logger, task
from prefect.client.schemas.objects import State, TaskRun
from prefect.states import Failed

from bagport.episode import EpisodeRequest, convert_episode
from bagport.errors import BagportError, TransientError

__all__ = ["convert_episode_task", "retry_only_transient"]


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
def convert_episode_task(request: dict[str, Any], label: str) -> dict[str, Any] | State[Any]:
    """Returns the staged episode's folder URI and a small summary, never arrays.

    A bad bag ends the task run in a Failed state whose message is bagport's one-paragraph
    error (no traceback in the logs); transient I/O errors raise, so Prefect retries them.
    """
    episode = EpisodeRequest(**request)
    try:
        summary = convert_episode(episode)
    except TransientError:
        raise
    except BagportError as err:
        get_run_logger().error("%s: %s", label, err)
        return Failed(message=str(err))
    read = summary.bag_read
    get_run_logger().info(
        "%s: %d frames staged at %s (bag %s, %s bytes read)",
        label, summary.frames, summary.dir_uri, read.get("access"), read.get("bytes_read"),
    )  # fmt: skip
    for warning in read.get("warnings", ()):
        get_run_logger().warning("%s: %s", label, warning)
    return {
        "episode_id": summary.episode_id,
        "dir_uri": summary.dir_uri,
        "bag_uri": summary.bag_uri,
        "frames": summary.frames,
        "tasks": list(summary.tasks),
        "qa_verdict": summary.qa.get("verdict"),
    }
