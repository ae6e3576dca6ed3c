"""Stopping a run's task runs that have not finished (``--fail-fast``, an interrupted run), on every runner."""

from __future__ import annotations

from typing import Any

from prefect.futures import PrefectFuture

__all__ = ["cancel_unfinished"]


def cancel_unfinished(futures: list[PrefectFuture[Any]]) -> int:
    """Cancel the episodes not finished yet; how many there were.

    Pending ones never start; one already running on a process or thread finishes and stages (a
    staged episode is complete or absent: ``episode.json`` is written last).
    """
    unfinished = 0
    for future in futures:
        wrapped = getattr(future, "wrapped_future", None)  # a concurrent.futures, distributed or Ray future
        if wrapped is None:
            continue
        if not hasattr(wrapped, "done"):
            unfinished += _cancel_ray(wrapped)
        elif not wrapped.done():
            wrapped.cancel()
            unfinished += 1
    return unfinished


def _cancel_ray(ref: Any) -> bool:
    """Cancel a Ray task unless it finished; whether it had not.

    Unlike a process or thread, Ray interrupts a running task too; it stages nothing then, as
    ``episode.json`` is written last, and a re-run converts that episode again.
    """
    import ray  # noqa: PLC0415 - only a Ray future gets here

    ready, _ = ray.wait([ref], timeout=0)
    if ready:
        return False
    ray.cancel(ref)
    return True
