"""The local process pool's workers, forked from one warm process instead of spawned.

Prefect's process pool spawns each worker as a fresh interpreter. Before its first episode a spawned
worker imports Prefect and bagport (about 1.3 s of CPU on 2 cores) and, when it rebuilds the flow's
context, every installed Prefect collection (``prefect-dask`` imports Dask's ``distributed``: another
0.6 s). :class:`flows.runners.WarmProcessPoolTaskRunner` forks its workers from a forkserver that did
all that once (:mod:`flows.worker_preload`), so a worker starts with it done.

:func:`start` is called as soon as a run on the local process pool is known (``run_convert``, before
the wait for the temporary Prefect server), so the forkserver's imports use the core the CLI leaves
idle while that server boots. Standard library only.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import threading

__all__ = ["PRELOAD", "available", "start", "stop", "stop_in_background"]

PRELOAD = ("flows.worker_preload",)
"""What the forkserver imports before it forks a worker."""


def available() -> bool:
    """Whether this platform has the forkserver start method (Linux and macOS do; Windows does not)."""
    return "forkserver" in multiprocessing.get_all_start_methods()


def start() -> bool:
    """Start the forkserver with :data:`PRELOAD` unless it runs already; whether workers can fork
    from it. Returns at once: the forkserver imports in its own process."""
    if not available():
        return False
    multiprocessing.forkserver.set_forkserver_preload(list(PRELOAD))
    multiprocessing.forkserver.ensure_running()
    return True


def stop() -> None:
    """Stop the forkserver and wait for it (its workers have ended with the pool), as for any process a
    run starts: nothing is left behind, and the run's CPU time includes the workers' (``bench/run.py``
    counts the CPU of the processes the run waited for). Python has no public call for it; where its
    private one is missing the forkserver ends with this process instead."""
    stop_forkserver = getattr(getattr(multiprocessing.forkserver, "_forkserver", None), "_stop", None)
    if stop_forkserver is not None:
        stop_forkserver()


def stop_in_background() -> threading.Thread:
    """:func:`stop` on a thread of its own, to join later: the forkserver's exit (a quarter of a second
    of interpreter teardown) overlaps what the run still does, such as stopping its temporary server."""
    stopping = threading.Thread(target=stop, name="bagport-forkserver-stop")
    stopping.start()
    return stopping
