"""Where a conversion runs: the Prefect API it talks to, and the task runner of its episodes."""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import contextmanager
from multiprocessing.connection import Connection
from typing import Any, Self

from prefect.context import refresh_global_settings_context
from prefect.events.worker import EventsWorker
from prefect.logging.handlers import APILogWorker
from prefect.settings import (
    PREFECT_API_SSL_CERT_FILE,
    PREFECT_API_URL,
    PREFECT_CLIENT_CSRF_SUPPORT_ENABLED,
    PREFECT_FLOWS_HEARTBEAT_FREQUENCY,
    get_current_settings,
    temporary_settings,
)
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, _initialize_process_pool_worker

from bagport.config import ConvertConfig
from bagport.errors import BagportError
from flows import forkserver
from flows.lifeline import when_cut
from flows.local_server import (
    LOOPBACK_CA,
    LocalServer,
    ServerStartError,
    ServerUnreachableError,
    check_reachable,
    take_launched,
)

__all__ = [
    "RayMissingError",
    "ServerDownError",
    "WarmProcessPoolTaskRunner",
    "dask_runner",
    "prefect_api",
    "ray_runner",
]


@contextmanager
def prefect_api() -> Iterator[None]:
    """Use the configured Prefect API, else one temporary local server shared by every worker
    (:class:`flows.local_server.LocalServer`: Prefect's app on IMMEDIATE SQLite transactions).

    Without this, each process-pool worker would start a temporary server of its own
    (15-20 s each here), because Prefect does not pass its ephemeral server's URL on. The CLI
    launches the server before its heavy imports (:func:`flows.local_server.launch`), so it
    boots while bagport and Prefect import.
    """
    launched = take_launched()
    if launched is not None:
        try:
            if str(get_current_settings().api.url or "") != launched.api_url:
                refresh_global_settings_context()  # Prefect imported before launch() set the URL (in-process CLI)
            # the run's settings are built while the server boots (0.06 s of pydantic-settings), not after
            with _on_temporary_server():
                _wait_ready(launched)
                yield
        finally:
            launched.stop()
            refresh_global_settings_context()
        return
    if get_current_settings().api.url:
        _require_server(str(get_current_settings().api.url))
        yield
        return
    # called as a library (not through the CLI): the same temporary server the CLI launches, started now
    # with the caller's Prefect settings (a profile, temporary_settings), as Prefect's own would be
    server = LocalServer(get_current_settings().to_environment_variables(exclude_unset=True))
    previous = os.environ.get("PREFECT_API_URL")
    try:
        _wait_ready(server)
        os.environ["PREFECT_API_URL"] = server.api_url
        # threads Prefect starts outside any settings context (the process pool's message forwarder, which
        # sends the workers' events) read Prefect's global settings, taken from the environment when Prefect
        # was imported: without this they would start a temporary server of their own and send the
        # workers' events there
        refresh_global_settings_context()
        with temporary_settings({PREFECT_API_URL: server.api_url}), _on_temporary_server():
            yield
    finally:
        if previous is None:
            os.environ.pop("PREFECT_API_URL", None)
        else:
            os.environ["PREFECT_API_URL"] = previous
        refresh_global_settings_context()
        server.stop()


class ServerDownError(BagportError):
    """The Prefect API does not answer: the configured one, or bagport's temporary server, which did not
    start."""


def _wait_ready(server: LocalServer) -> None:
    """The temporary server's health check; one that exits or never answers is one paragraph (exit 2)."""
    try:
        server.wait_ready(get_current_settings().server.ephemeral.startup_timeout_seconds)
    except ServerStartError as err:
        raise ServerDownError(str(err)) from None


def _require_server(api_url: str) -> None:
    """One paragraph (exit 2) instead of Prefect's long traceback when the configured server is down."""
    try:
        check_reachable(api_url)
    except ServerUnreachableError as err:
        raise ServerDownError(str(err)) from None


@contextmanager
def _on_temporary_server() -> Iterator[None]:
    """A run on bagport's temporary server: no flow-run heartbeats, no CSRF tokens, a one-certificate CA
    file for its clients' TLS contexts (:data:`flows.local_server.LOOPBACK_CA`: plain HTTP, never used),
    and queued logs and events delivered while the server still listens.

    Heartbeats let a server mark a flow run whose process died as crashed; the temporary server stops
    with the run (it has a lifeline, ``flows/local_server.py``), so nothing could ever watch them. They
    cost a run up to 1 s at its end: Prefect joins their thread, which sleeps in 1 s steps. The temporary
    server checks no CSRF token (:class:`flows.local_server.LocalServer` turns that off: loopback, no
    UI), so a client fetching one is a request for nothing, made by every client a task run creates.
    A configured server (``PREFECT_API_URL``, a deployment) keeps both.
    """
    try:
        with temporary_settings(
            {
                PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None,
                PREFECT_CLIENT_CSRF_SUPPORT_ENABLED: False,
                PREFECT_API_SSL_CERT_FILE: str(LOOPBACK_CA),
            }
        ):
            yield
    finally:
        APILogWorker.drain_all(timeout=10)
        EventsWorker.drain_all(timeout=10)


def dask_runner(config: ConvertConfig, workers: int) -> TaskRunner[Any]:
    """Dask through prefect-dask: an existing scheduler, or a local cluster of worker processes.

    Workers share no disk with the flow: bags, staging and output move as fsspec URIs.
    One thread per worker keeps encoder memory per worker predictable.
    """
    from prefect_dask.task_runners import DaskTaskRunner  # noqa: PLC0415 - only when asked for

    if config.dask_address:
        runner: TaskRunner[Any] = DaskTaskRunner(address=config.dask_address)
    else:
        runner = DaskTaskRunner(
            cluster_kwargs={
                "n_workers": workers,
                "threads_per_worker": 1,
                "processes": True,
                # no dashboard, and the scheduler's HTTP endpoint (health, metrics) on a free port rather
                # than Dask's 8787, which a second run on the host would find taken
                "dashboard_address": None,
                "scheduler_kwargs": {"dashboard_address": ":0"},
            }
        )
    return runner


class RayMissingError(BagportError):
    """``--runner ray`` without the ``ray`` extra installed."""

    def __init__(self, missing: str) -> None:
        super().__init__(
            f"--runner ray needs prefect-ray and Ray, which are not installed here ({missing}). "
            "Fix: pip install 'bagport[ray]' (uv sync --extra ray; make setup installs every extra), "
            "or choose --runner process, thread or dask."
        )


def ray_runner(config: ConvertConfig, workers: int) -> TaskRunner[Any]:
    """Ray through prefect-ray: an existing cluster, or a local instance of ``workers`` CPUs.

    Each episode is a Ray task holding Ray's default of one CPU, so a node with N CPUs converts
    at most N episodes at once, like one Dask worker thread per episode. Workers share no disk
    with the flow: bags, staging and output move as fsspec URIs.
    """
    try:
        from prefect_ray import RayTaskRunner  # noqa: PLC0415 - only when asked for
    except ImportError as err:
        raise RayMissingError(str(err)) from err

    runner: TaskRunner[Any]
    log_kwargs: dict[str, Any] = {"logging_level": _ray_logging_level()}
    if config.ray_address == "auto":
        # prefect-ray would drop "auto" and start a local instance where none runs; Ray's "auto"
        # connects to the cluster this machine belongs to, or fails.
        runner = RayTaskRunner(init_kwargs={"address": "auto", **log_kwargs})
    elif config.ray_address:
        runner = RayTaskRunner(address=config.ray_address, init_kwargs=log_kwargs)
    else:
        # Ray's default for a new local instance, said explicitly: token authentication (Ray warns on every
        # start when the mode is left unset). A mode set in the environment is kept.
        os.environ.setdefault("RAY_AUTH_MODE", "token")
        # "local": a fresh instance even where one runs already (ray.init would join that one).
        runner = RayTaskRunner(
            init_kwargs={
                "address": "local",
                "num_cpus": workers,
                "num_gpus": 0,
                "include_dashboard": False,
                **log_kwargs,
            }
        )
    return runner


def _ray_logging_level() -> int:
    """Ray's driver log level: Prefect's, which ``bagport convert`` sets from ``--verbose``/``--quiet``
    (flows/cli.py: Ray's INFO lines, its instance started or the cluster joined, with ``--verbose`` only, its
    errors alone with ``--quiet``) and a deployment's worker leaves at Prefect's default (INFO)."""
    level = logging.getLevelName(str(get_current_settings().logging.level).upper())
    return level if isinstance(level, int) else logging.WARNING


def _start_forked_worker(
    environment: Mapping[str, str],
    lifeline: Connection,
    message_queue: Any,
    initializer: Callable[..., None] | None,
    initargs: tuple[Any, ...],
) -> None:
    """A forked worker's start: the flow process's environment (the forkserver has its own, from when it
    started) and Prefect's global settings read from it, as a spawned worker has them; a thread that ends
    the worker when the flow process is gone (``lifeline``: its other end only the flow process holds;
    a killed flow process would otherwise leave the workers waiting for work forever, and with them the
    forkserver); then Prefect's own worker set-up (logs and events forwarded to the flow process).

    Prefect's settings are read again only when the environments differ: the forkserver started from the
    flow process in the CLI, with this environment, and reading them costs a worker 0.1 s."""
    if dict(os.environ) != dict(environment):
        os.environ.clear()
        os.environ.update(environment)
        refresh_global_settings_context()
    # EX_SOFTWARE: the flow process is gone, nothing waits for this worker's work
    when_cut(lifeline, lambda: os._exit(70))
    _initialize_process_pool_worker(message_queue, initializer, initargs)


class WarmProcessPoolTaskRunner(ProcessPoolTaskRunner):
    """Prefect's process pool, its workers forked from bagport's warm forkserver (:mod:`flows.forkserver`:
    Prefect, bagport and Prefect's collections imported once) instead of spawned.

    Everything else is Prefect's: its worker set-up (logs and events forwarded to this process), message
    forwarder, resolver threads, submission and shutdown. ``__enter__`` is Prefect 3.8's own with the
    forkserver's context in place of ``spawn`` and the worker start above. ``tests/flows/test_runners.py``
    runs a flow on it (workers forked warm, the flow's settings in their threads, their logs on the
    server), so a Prefect upgrade that changes those internals fails there. Spawned, as Prefect's are,
    where the platform has no forkserver, and when entered inside a pool worker (Prefect enters a copy
    of the flow's runner in each worker that rebuilds the flow's context; it submits nothing there)."""

    _lifeline: tuple[Connection, Connection] | tuple[()] = ()
    """The workers' lifeline (read end for them, write end kept here) while entered on the forkserver."""

    def __enter__(self) -> Self:
        if multiprocessing.parent_process() is not None or not forkserver.start():
            return super().__enter__()
        TaskRunner.__enter__(self)
        context = multiprocessing.get_context("forkserver")
        self._lifeline = context.Pipe(duplex=False)  # (read end for the workers, write end kept here)
        self._subprocess_message_queue = context.Queue()
        self._message_forwarding_thread = threading.Thread(
            target=self._forward_subprocess_messages,
            name="ProcessPoolTaskRunnerMessageForwarder",
            daemon=True,
        )
        self._message_forwarding_thread.start()
        try:
            self._executor = ProcessPoolExecutor(
                max_workers=self._max_workers,
                mp_context=context,
                initializer=_start_forked_worker,
                initargs=(
                    dict(os.environ),
                    self._lifeline[0],
                    self._subprocess_message_queue,
                    self._initializer,
                    self._initargs,
                ),
            )
            self._resolver_executor = ThreadPoolExecutor(max_workers=self._max_workers)
        except Exception:
            if self._executor is not None:
                self._executor.shutdown(cancel_futures=True, wait=True)
                self._executor = None
            self._stop_message_forwarding()
            self._close_lifeline()
            raise
        return self

    def __exit__(self, exc_type: Any, exc_value: Any, traceback: Any) -> None:
        try:
            super().__exit__(exc_type, exc_value, traceback)  # the workers have ended
        finally:
            self._close_lifeline()

    def _close_lifeline(self) -> None:
        for end in self._lifeline:
            end.close()
        self._lifeline = ()
