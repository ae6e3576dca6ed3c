"""Where a conversion runs: the Prefect API it talks to, and the task runner of its episodes."""

from __future__ import annotations

import multiprocessing
import os
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Self

from prefect.events.worker import EventsWorker
from prefect.logging.handlers import APILogWorker
from prefect.settings import PREFECT_API_URL, get_current_settings, temporary_settings
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, _initialize_process_pool_worker

from bagport.config import ConvertConfig
from bagport.errors import BagportError
from flows.local_server import ServerUnreachableError, check_reachable, take_launched

__all__ = [
    "EarlyProcessPoolTaskRunner",
    "RayMissingError",
    "ServerDownError",
    "dask_runner",
    "prefect_api",
    "ray_runner",
]


@contextmanager
def prefect_api() -> Iterator[None]:
    """Use the configured Prefect API, else one temporary local server shared by every worker.

    Without this, each process-pool worker would start a temporary server of its own
    (15-20 s each here), because Prefect does not pass its ephemeral server's URL on. The CLI
    launches the server before its heavy imports (:func:`flows.local_server.launch`), so it
    boots while bagport and Prefect import.
    """
    launched = take_launched()
    if launched is not None:
        try:
            launched.wait_ready(get_current_settings().server.ephemeral.startup_timeout_seconds)
            with _draining():
                yield
        finally:
            launched.stop()
        return
    if get_current_settings().api.url:
        _require_server(str(get_current_settings().api.url))
        yield
        return
    from prefect.server.api.server import SubprocessASGIServer  # noqa: PLC0415 - only without a server

    server = SubprocessASGIServer()
    server.start(timeout=get_current_settings().server.ephemeral.startup_timeout_seconds)
    previous = os.environ.get("PREFECT_API_URL")
    os.environ["PREFECT_API_URL"] = server.api_url
    try:
        with temporary_settings({PREFECT_API_URL: server.api_url}), _draining():
            yield
    finally:
        if previous is None:
            os.environ.pop("PREFECT_API_URL", None)
        else:
            os.environ["PREFECT_API_URL"] = previous
        server.stop()


class ServerDownError(BagportError):
    """The configured Prefect API does not answer."""


def _require_server(api_url: str) -> None:
    """One paragraph (exit 2) instead of Prefect's long traceback when the configured server is down."""
    try:
        check_reachable(api_url)
    except ServerUnreachableError as err:
        raise ServerDownError(str(err)) from None


@contextmanager
def _draining() -> Iterator[None]:
    """Deliver queued logs and events while the server still listens."""
    try:
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
                "dashboard_address": None,
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
    if config.ray_address == "auto":
        # prefect-ray would drop "auto" and start a local instance where none runs; Ray's "auto"
        # connects to the cluster this machine belongs to, or fails.
        runner = RayTaskRunner(init_kwargs={"address": "auto"})
    elif config.ray_address:
        runner = RayTaskRunner(address=config.ray_address)
    else:
        # "local": a fresh instance even where one runs already (ray.init would join that one).
        runner = RayTaskRunner(
            init_kwargs={"address": "local", "num_cpus": workers, "num_gpus": 0, "include_dashboard": False}
        )
    return runner


def _import_episode_task() -> None:
    """Run in each new worker: import what an episode task needs while the flow process waits."""
    import tasks.episode  # noqa: F401, PLC0415 - the import is the point


class EarlyProcessPoolTaskRunner(ProcessPoolTaskRunner):
    """Prefect's process pool, whose worker processes can start before the flow does.

    Each spawned worker imports Prefect and bagport (about 2 s here) before its first episode;
    :meth:`start_early` spawns them and imports the episode task while the temporary server
    boots, and the flow's runner (a :meth:`duplicate`) adopts that pool once. Without
    :meth:`start_early`, or on a second flow run, it is Prefect's runner unchanged.
    """

    def __init__(self, max_workers: int | None = None) -> None:
        super().__init__(max_workers=max_workers)
        self._early: list[tuple[Any, ProcessPoolExecutor]] = []  # shared with duplicates

    def duplicate(self) -> Self:
        copy = super().duplicate()
        copy._early = self._early
        return copy

    def start_early(self) -> None:
        """Spawn the workers now, each importing the episode task."""
        spawn = multiprocessing.get_context("spawn")
        queue = spawn.Queue()  # the workers' events and logs, forwarded once a flow adopts the pool
        executor = ProcessPoolExecutor(
            max_workers=self._max_workers,
            mp_context=spawn,
            initializer=_initialize_process_pool_worker,
            initargs=(queue, None, ()),
        )
        for _ in range(self._max_workers):  # one spawn per submit while no worker idles
            executor.submit(_import_episode_task)
        self._early.append((queue, executor))

    def close_early(self) -> None:
        """Stop a pool no flow adopted (the run failed before its flow started)."""
        while self._early:
            queue, executor = self._early.pop()
            executor.shutdown(cancel_futures=True, wait=True)
            queue.close()

    def __enter__(self) -> Self:
        if not self._early:
            return super().__enter__()
        queue, executor = self._early.pop()
        TaskRunner.__enter__(self)
        self._subprocess_message_queue = queue
        self._executor = executor
        self._message_forwarding_thread = threading.Thread(
            target=self._forward_subprocess_messages,
            name="ProcessPoolTaskRunnerMessageForwarder",
            daemon=True,
        )
        self._message_forwarding_thread.start()
        self._resolver_executor = ThreadPoolExecutor(max_workers=self._max_workers)
        return self
