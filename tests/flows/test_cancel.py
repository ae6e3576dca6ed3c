"""Cancelling a run's unfinished task runs: pending ones never start, finished ones are not counted.

The runners' own futures (a process pool's, Dask's, Ray's) are exercised end to end by
``test_fail_fast.py``; here the counting and the cancelling on futures in a known state.
"""

from __future__ import annotations

import threading
import uuid
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from prefect.futures import PrefectConcurrentFuture, PrefectFuture

from flows.cancel import cancel_unfinished


def _prefect(wrapped: Future[Any]) -> PrefectFuture[Any]:
    return PrefectConcurrentFuture(uuid.uuid4(), wrapped)


def test_pending_task_runs_are_cancelled_and_counted_a_finished_one_is_left() -> None:
    release = threading.Event()
    with ThreadPoolExecutor(max_workers=1) as pool:
        running = pool.submit(release.wait, 10)  # holds the only thread: the next two stay pending
        pending = [pool.submit(lambda: "never"), pool.submit(lambda: "never")]
        finished: Future[Any] = Future()
        finished.set_result("staged")
        try:
            futures = [_prefect(finished), *(_prefect(f) for f in pending)]
            assert cancel_unfinished(futures) == 2
            assert all(f.cancelled() for f in pending)
            assert finished.result() == "staged" and not finished.cancelled()
        finally:
            release.set()
        assert running.result() is True  # a running task run finishes (it stages, or nothing)


def test_a_future_without_a_wrapped_one_is_not_counted() -> None:
    class Bare:
        """A future of a runner that exposes nothing to cancel (what the flow may see on a new runner)."""

    assert cancel_unfinished([Bare()]) == 0  # type: ignore[list-item]
