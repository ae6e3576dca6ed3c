"""Split one bag into its episodes (a cheap scan of the event / done / stream stamps), before the map."""

from __future__ import annotations

from typing import Any

from prefect import get_run_logger, task
from prefect.client.schemas.objects import State
from prefect.states import Failed

from bagport.episode import EpisodeRequest
from bagport.errors import BagportError, TransientError
from bagport.segment import SegmentedBag, segment_request
from tasks.episode import retry_only_transient

__all__ = ["segment_bag_task"]


@task(
    name="segment-bag",
    task_run_name="segment {label}",
    retries=2,
    retry_delay_seconds=[2, 10],
    retry_condition_fn=retry_only_transient,
    tags=["bagport", "segment"],
)
def segment_bag_task(request: EpisodeRequest, label: str) -> SegmentedBag | State[Any]:
    """The bag's episode requests and what segmentation left out, with the reasons."""
    try:
        found = segment_request(request)
    except TransientError:
        raise
    except BagportError as err:
        get_run_logger().error("%s: %s", label, err)
        return Failed(message=str(err))
    logger = get_run_logger()
    cached = " (segmentation from the staging store, bag not read)" if found.cached else ""
    logger.info("%s: %d episode(s)%s", label, len(found.requests), cached)
    for reason in found.ignored:
        logger.warning("%s: left out %s", label, reason)
    return found
