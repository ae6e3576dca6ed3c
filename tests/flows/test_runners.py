"""Where a run's tasks run: bagport's temporary Prefect server as a library caller gets it
(``prefect_api()`` without the CLI: one server for the whole run, Prefect's own threads included), and
the local process pool's workers forked warm from the forkserver."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import psutil
import pytest
from prefect import flow, get_client, get_run_logger, task
from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterName, LogFilter, LogFilterFlowRunId
from prefect.events.worker import EventsWorker
from prefect.server.api.server import SubprocessASGIServer
from prefect.settings import PREFECT_API_URL, get_current_settings, temporary_settings

from bagport.config import ConvertConfig
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows import forkserver
from flows.convert import run_config, run_convert
from flows.local_server import LOOPBACK_CA, LocalServer, loopback_listener
from flows.runners import ServerDownError, WarmProcessPoolTaskRunner, prefect_api
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

BAGS = ("a", "b", "c")


def _task_run_names(flow_run_name: str) -> set[str]:
    # the temporary server's database keeps earlier runs ($PREFECT_HOME/prefect.db): ask for this one
    flow_run = FlowRunFilter(name=FlowRunFilterName(any_=[flow_run_name]))
    with get_client(sync_client=True) as client:
        runs = client.read_task_runs(flow_run_filter=flow_run)
    return {run.name for run in runs if run.state is not None and run.state.is_completed()}


def test_a_library_run_on_the_process_pool_starts_no_other_server(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    started: list[str] = []
    start = SubprocessASGIServer.start

    def record_start(self: SubprocessASGIServer, *args: Any, **kwargs: Any) -> None:
        started.append(threading.current_thread().name)
        start(self, *args, **kwargs)

    monkeypatch.setattr(SubprocessASGIServer, "start", record_start)
    cameras = (  # the sample contract's cameras
        CameraSpec("front", "raw", "bgr8", height=32, width=32),
        CameraSpec("wrist", "jpeg", height=32, width=32),
    )
    for i, name in enumerate(BAGS):
        write_episode_bag(tmp_path / name, "mcap", EpisodeSpec(duration_s=0.5, seed=i, cameras=cameras))
    (tmp_path / "manifest.yaml").write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in BAGS))
    out = tmp_path / "ds"
    config = ConvertConfig(
        manifest=str(tmp_path / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(out),
        encoder=FAST_CODEC, runner="process", workers=2,
    )  # fmt: skip
    expected = {f"convert {name}" for name in BAGS}
    with prefect_api():
        assert run_config(config).episodes == len(BAGS)
        # the task runs, as the UI lists them (their last states may arrive a moment after the flow's end)
        deadline = time.monotonic() + 30
        while not expected <= (names := _task_run_names(f"convert {out}")) and time.monotonic() < deadline:
            time.sleep(0.5)
    # Prefect's forwarder of the workers' events (and its global event loop thread) once read the settings
    # Prefect took from the environment at import, without the API URL: each started a temporary server of
    # its own (about 2 s of a 12 s run here) and the workers' events went there
    assert started == []
    assert expected <= names


@task(name="probe-worker")
def _probe_worker() -> tuple[bool, str | None, int, str]:
    """Whether this worker started warm (forked from the forkserver), the API URL a thread it starts sees
    (threads start outside any settings context: Prefect's global settings), how many processes it
    started itself, and the first folder it imports from."""
    get_run_logger().warning("hello from a pool worker")  # WARNING: scripts/env.sh sends no INFO to the API
    seen: list[str | None] = []
    thread = threading.Thread(target=lambda: seen.append(get_current_settings().api.url))
    thread.start()
    thread.join()
    return "flows.worker_preload" in sys.modules, seen[0], len(psutil.Process().children()), sys.path[0]


@flow(name="bagport-test-warm-pool")
def _probe_flow() -> list[tuple[bool, str | None, int, str]]:
    return [future.result() for future in [_probe_worker.submit() for _ in range(4)]]


def test_pool_workers_fork_warm_with_the_flows_settings_and_their_logs_arrive(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    assert forkserver.start()  # before the API URL is set, as run_convert starts it
    monkeypatch.syspath_prepend(str(tmp_path))  # and before this folder is on the import path
    with prefect_api():
        runner = WarmProcessPoolTaskRunner(max_workers=2)
        state = _probe_flow.with_options(task_runner=runner)(return_state=True)  # type: ignore[arg-type]
        # a worker: imports done in the forkserver; the flow process's API, not the forkserver's settings
        # (which would have a thread start a server of its own); no process of its own (Prefect enters a
        # copy of the flow's runner in each worker: it must not start a forkserver there); the flow
        # process's import path (multiprocessing sends it to each process it starts), as when spawned
        assert state.result() == [(True, os.environ["PREFECT_API_URL"], 0, str(tmp_path))] * 4
        flow_run_id = state.state_details.flow_run_id
        assert flow_run_id is not None
        deadline, said = time.monotonic() + 30, list[Any]()
        while len(said) < 4 and time.monotonic() < deadline:
            with get_client(sync_client=True) as client:
                logs = client.read_logs(
                    log_filter=LogFilter(flow_run_id=LogFilterFlowRunId(any_=[flow_run_id]))
                )
            said = [log for log in logs if log.message == "hello from a pool worker"]
            time.sleep(0.5)
    assert len(said) == 4  # each worker's log line reached the server
    assert _forkservers()
    forkserver.stop()  # as run_convert does at its end: the forkserver is waited for, nothing left behind
    assert not _forkservers()


def _forkservers() -> list[psutil.Process]:
    return [p for p in psutil.Process().children() if "forkserver" in " ".join(p.cmdline())]


@flow(name="bagport-noop")
def _noop_flow() -> None:
    """A flow to create a run of through the API."""


@flow(name="bagport-test-heartbeats")
def _heartbeat_seconds() -> int | None:
    """The flow-run heartbeat interval Prefect's flow engine reads (``None``: no heartbeats)."""
    return get_current_settings().flows.heartbeat_frequency


def test_heartbeats_and_csrf_tokens_go_to_a_configured_server_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Nothing watches heartbeats on the temporary server, which stops with the run (and joining their
    thread cost up to 1 s per run), and it checks no CSRF token (loopback, no UI: fetching one was a
    request per client for nothing), even where the environment turns servers' CSRF protection on; its
    clients load a one-certificate CA file (plain HTTP: never used; a bundle cost 30-60 ms per client). A
    server the user configured keeps all three (heartbeats mark dead runs crashed; its TLS settings)."""
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    monkeypatch.setenv("PREFECT_SERVER_API_CSRF_PROTECTION_ENABLED", "true")
    default = get_current_settings().flows.heartbeat_frequency
    users_cert_file = get_current_settings().api.ssl_cert_file
    assert default is not None
    assert users_cert_file != str(LOOPBACK_CA)
    with prefect_api():
        assert _heartbeat_seconds() is None
        assert not get_current_settings().client.csrf_support_enabled
        assert get_current_settings().api.ssl_cert_file == str(LOOPBACK_CA)
        with get_client(sync_client=True) as client:  # a state-changing request, without a token
            assert client.create_flow_run(_noop_flow).id is not None
    users = LocalServer()  # stands for the user's own server
    try:
        users.wait_ready(120)
        monkeypatch.setenv("PREFECT_API_URL", users.api_url)
        with temporary_settings({PREFECT_API_URL: users.api_url}), prefect_api():
            assert _heartbeat_seconds() == default
            assert get_current_settings().client.csrf_support_enabled
            assert get_current_settings().api.ssl_cert_file == users_cert_file
            EventsWorker.drain_all(timeout=30)  # its heartbeat event, sent before that server stops
    finally:
        users.stop()


def test_a_run_on_the_warm_pool_leaves_no_forkserver(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``run_convert`` stops the forkserver it started (on a thread, while the temporary server stops)
    and waits for it before it returns."""
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    for i, name in enumerate(BAGS[:2]):
        write_episode_bag(tmp_path / name, "mcap", EpisodeSpec(duration_s=0.3, seed=i))
    (tmp_path / "manifest.yaml").write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in BAGS[:2]))
    config = ConvertConfig(
        manifest=str(tmp_path / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(tmp_path / "ds"),
        encoder=FAST_CODEC, runner="process", workers=2,
    )  # fmt: skip
    forkserver.stop()  # one an earlier test's flow left in this process (a flow called without run_convert)
    assert not _forkservers()
    assert run_convert(config).episodes == 2
    assert not _forkservers()
    assert not [t for t in threading.enumerate() if t.name == "bagport-forkserver-stop"]


def test_a_run_whose_server_is_down_leaves_no_forkserver(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The forkserver starts before the configured API is checked; a server that does not answer ends the
    run there (one paragraph, exit 2), and the forkserver with it."""
    with loopback_listener() as listener:  # a port nothing answers on once closed
        dead_url = f"http://127.0.0.1:{listener.getsockname()[1]}/api"
    monkeypatch.setenv("PREFECT_API_URL", dead_url)
    write_episode_bag(tmp_path / BAGS[0], "mcap", EpisodeSpec(duration_s=0.3, seed=0))
    config = ConvertConfig(
        bags_glob=str(tmp_path / "*"), contract=str(SAMPLE_CONTRACT), output=str(tmp_path / "ds"),
        encoder=FAST_CODEC, runner="process", workers=2,
    )  # fmt: skip
    with temporary_settings({PREFECT_API_URL: dead_url}), pytest.raises(ServerDownError):
        run_convert(config)
    assert not _forkservers()


def test_the_cli_forks_its_forkserver_before_prefects_imports_against_a_running_server(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With a configured API the flow starts once Prefect is imported: the forkserver is started before
    those imports (then its workers are ready for the first task runs); with a temporary server after
    them (the fork then has them); with nothing to convert or a single worker, never. The CLI's
    forkserver is a fork of the CLI when it is the ``bagport`` program, not when ``main`` is called from
    Python (a test, a script: forking that caller would copy whatever it holds)."""
    import flows.cli  # noqa: PLC0415 - the module under test
    import flows.convert  # noqa: PLC0415 - its entry is replaced below
    import flows.import_gc  # noqa: PLC0415 - its imports are recorded below

    calls: list[str] = []

    def start(*, fork_this_process: bool = False) -> bool:
        calls.append(f"forkserver fork={fork_this_process}")
        return True

    @contextmanager
    def imports() -> Iterator[None]:
        calls.append("imports")
        yield

    monkeypatch.setattr(forkserver, "start", start)
    monkeypatch.setattr(flows.import_gc, "paused", imports)
    monkeypatch.setattr(flows.convert, "run_convert", lambda config, plan: calls.append("flow"))
    config = ConvertConfig(
        bags_glob=str(tmp_path / "bags/*"),
        contract=str(SAMPLE_CONTRACT),
        output=str(tmp_path / "ds"),
        workers=2,
    )
    work, none = SimpleNamespace(requests=("a bag",)), SimpleNamespace(requests=())
    one_worker = config.model_copy(update={"workers": 1})  # a thread, no pool
    for options, plan, server_up, fork_cli, expected in (
        (config, work, True, True, ["forkserver fork=True", "imports", "flow"]),
        (config, work, False, True, ["imports", "forkserver fork=True", "flow"]),
        (
            config,
            work,
            False,
            False,
            ["imports", "forkserver fork=False", "flow"],
        ),  # main() called from Python
        (config, none, True, True, ["imports", "flow"]),
        (config, none, False, True, ["imports", "flow"]),
        (one_worker, work, True, True, ["imports", "flow"]),
    ):
        calls.clear()
        flows.cli._run_flow(options, plan, False, server_up=server_up, fork_cli=fork_cli)  # type: ignore[arg-type]
        assert calls == expected, (server_up, plan, options.workers, fork_cli)
