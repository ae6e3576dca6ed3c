"""The local process pool's workers, forked from one warm process instead of spawned.

Prefect's process pool spawns each worker as a fresh interpreter. Before its first episode a spawned
worker imports Prefect and bagport (about 1.3 s of CPU on 2 cores) and, when it rebuilds the flow's
context, every installed Prefect collection (``prefect-dask`` imports Dask's ``distributed``: another
0.6 s). :class:`flows.runners.WarmProcessPoolTaskRunner` forks its workers from a forkserver that did
all that once (:mod:`flows.worker_preload`), so a worker starts with it done.

:func:`start` is called as soon as a run on the local process pool is known (``run_convert``, before
the wait for the temporary Prefect server), so the forkserver's imports use the core the CLI leaves
idle while that server boots. The ``bagport`` program starts it with ``fork_this_process``: the
forkserver is a fork of the CLI and imports only what it still lacks (:func:`_start_forked`), instead
of a fresh interpreter importing everything again. With a temporary server the CLI has imported
Prefect and bagport by then: 1.2-1.9 CPU s less per run, on the two cores the server's boot needs too
(W3: 15.4 s against 16.0 s, three interleaved pairs); against a running server it forks before those
imports, so the flow's first task runs do not wait for them. Standard library only.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import os
import socket
import threading
import traceback
import warnings
from multiprocessing import connection, resource_tracker, util
from pathlib import Path
from typing import Any, NoReturn

__all__ = ["PRELOAD", "available", "start", "stop", "stop_in_background"]

PRELOAD = ("flows.worker_preload",)
"""What the forkserver imports before it forks a worker."""


def available() -> bool:
    """Whether this platform has the forkserver start method (Linux and macOS do; Windows does not)."""
    return "forkserver" in multiprocessing.get_all_start_methods()


def start(*, fork_this_process: bool = False) -> bool:
    """Start the forkserver with :data:`PRELOAD` unless it runs already; whether workers can fork
    from it. Returns at once: the forkserver imports in its own process.

    ``fork_this_process``: the forkserver is forked from this process (which must be a fresh one, such as
    the CLI's: its whole state is the forkserver's, then each worker's), when it runs one thread only
    (a fork keeps no other thread, and a lock another thread held would stay held); else, and where
    Python cannot fork, a fresh interpreter as multiprocessing starts it."""
    if not available():
        return False
    multiprocessing.forkserver.set_forkserver_preload(list(PRELOAD))
    if fork_this_process and hasattr(os, "fork") and threading.active_count() == 1:
        _start_forked()
    else:
        multiprocessing.forkserver.ensure_running()
    return True


def _start_forked() -> None:
    """What ``multiprocessing.forkserver.ensure_running`` does (its listening socket, its "alive" pipe,
    its state), with the forkserver forked from this process instead of spawned. The child runs
    multiprocessing's own forkserver loop, which imports :data:`PRELOAD` (only what this process has
    not imported), and leaves by ``os._exit``: this process's exit handlers (stopping the temporary
    server) are not its own. Where the fork fails, the forkserver is a fresh interpreter as usual."""
    server: Any = getattr(multiprocessing.forkserver, "_forkserver")  # noqa: B009 - the module's one instance
    with server._lock:
        resource_tracker.ensure_running()  # before the fork: the workers share this process's tracker
        if server._forkserver_pid is not None:
            return
        with socket.socket(socket.AF_UNIX) as listener:
            address = connection.arbitrary_address("AF_UNIX")  # type: ignore[attr-defined]
            listener.bind(address)
            if not util.is_abstract_socket_namespace(address):
                Path(address).chmod(0o600)
            listener.listen()
            alive_r, alive_w = os.pipe()  # the forkserver ends when every write end is closed
            pid: int | None
            try:
                pid = _fork()
            except OSError:
                os.close(alive_r)
                os.close(alive_w)
                pid = None
            if pid == 0:
                _serve(server, listener, alive_r, alive_w)
            if pid is not None:
                os.close(alive_r)
                server._forkserver_address = address
                server._forkserver_alive_fd = alive_w
                server._forkserver_pid = pid
    if pid is None:  # no fork (out of memory, a process limit): a spawned forkserver
        multiprocessing.forkserver.ensure_running()


def _fork() -> int:
    with warnings.catch_warnings():
        # Python warns of any thread it did not start: numpy's BLAS and pyarrow's jemalloc keep one
        # each, and both reset them in a forked child, as every forkserver's fork of a worker (whose
        # imports start the same threads) relies on; no Python thread runs here (start() checks)
        warnings.filterwarnings("ignore", r"This process .* is multi-threaded", DeprecationWarning)
        return os.fork()


def _serve(server: Any, listener: socket.socket, alive_r: int, alive_w: int) -> NoReturn:
    """The forked child: multiprocessing's forkserver loop, until the parent's end of the alive pipe
    closes. Its lock, held by the parent at the fork, is a fresh one here; a preload that fails prints
    its traceback and the forkserver exits 1 (the pool then reports its workers as broken)."""
    code = 0
    try:
        server._lock = threading.Lock()
        os.close(alive_w)
        multiprocessing.forkserver.main(listener.fileno(), alive_r, list(PRELOAD))
    except SystemExit:  # how its loop ends: the alive pipe closed
        pass
    except BaseException:  # the child's last word, then its exit
        traceback.print_exc()
        code = 1
    finally:
        os._exit(code)


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
