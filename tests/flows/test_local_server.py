"""The temporary Prefect server the CLI launches before its imports."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import ssl
import time
import urllib.error
import urllib.request
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from flows import local_server
from flows.local_server import LocalServer, ServerStartError, api_configured


@pytest.fixture
def no_prefect_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for name in ("PREFECT_API_URL", "PREFECT_PROFILE", "PREFECT_PROFILES_PATH"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_no_api_anywhere_means_a_temporary_server(no_prefect_config: Path) -> None:
    assert not api_configured()


def test_an_api_in_the_environment_is_used(no_prefect_config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PREFECT_API_URL", "http://prefect.example:4200/api")
    assert api_configured()


def test_an_api_in_the_active_profile_is_used(
    no_prefect_config: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    home = no_prefect_config / "home"
    home.mkdir()
    (home / "profiles.toml").write_text(
        'active = "fleet"\n[profiles.fleet]\nPREFECT_API_URL = "http://prefect.example:4200/api"\n'
        '[profiles.local]\nPREFECT_LOGGING_LEVEL = "INFO"\n'
    )
    assert api_configured()
    monkeypatch.setenv("PREFECT_PROFILE", "local")
    assert not api_configured()


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("prefect.toml", '[api]\nurl = "http://prefect.example:4200/api"\n'),
        ("pyproject.toml", '[tool.prefect.api]\nurl = "http://prefect.example:4200/api"\n'),
        (".env", "PREFECT_API_URL=http://prefect.example:4200/api\n"),
    ],
)
def test_an_api_in_project_settings_is_used(no_prefect_config: Path, name: str, text: str) -> None:
    (no_prefect_config / name).write_text(text)
    assert api_configured()


def test_the_server_makes_a_missing_prefect_home_for_its_database(tmp_path: Path) -> None:
    """SQLite makes the database file, not its folder: a fresh machine's PREFECT_HOME (or a new one set for
    a job) does not exist yet."""
    home = tmp_path / "new" / "prefect-home"
    server = LocalServer({"PREFECT_HOME": str(home)})
    assert home.is_dir()  # before Prefect's import in this process: it would warn, unable to make it
    try:
        server.wait_ready(120)
    finally:
        server.stop()
    assert (home / "prefect.db").is_file()
    database = tmp_path / "elsewhere" / "prefect.db"  # a configured SQLite file: the server makes its folder
    server = LocalServer({"PREFECT_API_DATABASE_CONNECTION_URL": f"sqlite+aiosqlite:///{database}"})
    try:
        server.wait_ready(120)
    finally:
        server.stop()
    assert database.is_file()


def test_a_server_that_dies_while_booting_is_reported_as_such() -> None:
    """Its health check waits on the bound listener for as long as the boot takes, and a server that exits
    meanwhile ends the wait at once (its connection is reset), not at the timeout."""
    server = LocalServer(
        {"PREFECT_API_DATABASE_CONNECTION_URL": "nodriver://nowhere"}
    )  # the app cannot start
    timeout_s = 120
    started_s = time.monotonic()
    try:
        with pytest.raises(ServerStartError, match=r"exited \(code \d+\) before it was ready"):
            server.wait_ready(timeout_s)
        assert time.monotonic() - started_s < timeout_s / 2  # at its exit, not at the timeout
    finally:
        server.stop()


@pytest.mark.filterwarnings("ignore:This process .* is multi-threaded:DeprecationWarning")  # the child only
def test_a_fork_of_the_owner_holds_no_lifeline_and_never_stops_the_server() -> None:  # checks and exits
    """The CLI's forkserver is a fork of the CLI: the server must end with the CLI, not with the last
    of its forks, and a fork's exit must not stop it."""
    server = LocalServer()
    try:
        lifeline_w = server._lifeline_w
        pid = os.fork()
        if pid == 0:  # the fork: its copy of the write end closed, its copy of the server let go
            code = 0
            try:
                os.fstat(lifeline_w)
                code = 3
            except OSError:
                code = 0 if server._process is None else 4
            os._exit(code)
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 0
        assert server._process is not None and server._process.poll() is None  # still the owner's
        os.fstat(lifeline_w)  # and still open here
    finally:
        server.stop(graceful=False)


@pytest.mark.slow
def test_the_server_answers_then_stops() -> None:
    server = LocalServer()
    try:
        server.wait_ready(120)
        with urllib.request.urlopen(f"{server.api_url}/health", timeout=5) as response:
            assert response.status == 200
    finally:
        server.stop()
    with pytest.raises(urllib.error.URLError):
        urllib.request.urlopen(f"{server.api_url}/health", timeout=2)


@pytest.mark.parametrize("ready", [False, True])
def test_an_unused_server_is_killed_at_once_and_nothing_is_left(ready: bool) -> None:
    """While it imports and once it answers: killed, not asked to stop, and waited for."""
    server = LocalServer()
    process = server._process
    assert process is not None
    if ready:
        server.wait_ready(120)
    server.stop(graceful=False)
    assert process.returncode == -signal.SIGKILL
    assert server._process is None
    with pytest.raises(ProcessLookupError):
        os.kill(process.pid, 0)


@pytest.mark.slow
def test_the_temporary_server_sends_no_telemetry(
    no_prefect_config: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 16 finding 6 / issue 21 item 8: offline, Prefect's telemetry logged a red ERROR (and once
    a "database is locked" traceback) on every run, and its client printed a usage-data notice."""
    monkeypatch.delenv("PREFECT_SERVER_ANALYTICS_ENABLED", raising=False)
    monkeypatch.delenv("DO_NOT_TRACK", raising=False)
    monkeypatch.setattr(local_server, "_launched", None)
    server = local_server.launch()
    assert server is not None
    try:
        assert os.environ["DO_NOT_TRACK"] == "1"
        server.wait_ready(120)  # exec'd: /proc shows the server's own environment, not its parent's
        assert server._process is not None
        environ = Path(f"/proc/{server._process.pid}/environ").read_bytes().split(b"\0")
        assert b"PREFECT_SERVER_ANALYTICS_ENABLED=false" in environ
    finally:
        local_server.take_launched()
        server.stop()
        monkeypatch.delenv("PREFECT_API_URL", raising=False)


@pytest.mark.slow
def test_the_port_is_held_from_the_start_and_the_callers_settings_reach_the_server(tmp_path: Path) -> None:
    """The port is bound before the server process starts (no other process can take it during the
    server's imports), and a library caller's Prefect settings are the server's too."""
    server = LocalServer({"PREFECT_HOME": str(tmp_path / "caller-home")})
    try:
        with socket.socket() as other, pytest.raises(OSError):
            other.bind(("127.0.0.1", server.port))  # before the server is even ready
        server.wait_ready(120)
        assert server._process is not None
        environ = Path(f"/proc/{server._process.pid}/environ").read_bytes().split(b"\0")
        assert f"PREFECT_HOME={tmp_path / 'caller-home'}".encode() in environ
        assert (tmp_path / "caller-home" / "prefect.db").exists()  # its database is the caller's
    finally:
        server.stop()


def test_the_listener_s_connections_send_without_delay() -> None:
    """Accepted connections inherit ``TCP_NODELAY`` from the listener handed to the server: uvicorn takes
    it as ``AF_UNIX`` and asyncio would not set the option (each API call then waited ~40 ms for the
    client's delayed ACK)."""
    with local_server.loopback_listener() as listener, socket.create_connection(listener.getsockname()):
        accepted, _ = listener.accept()
        with accepted:
            assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0


def _peer_socket_option(pid: int, peer: tuple[str, int]) -> int:
    """``TCP_NODELAY`` of the socket in process ``pid`` connected to ``peer`` (``pidfd_getfd``)."""
    import ctypes  # noqa: PLC0415 - Linux-only helper

    libc = ctypes.CDLL(None, use_errno=True)
    pidfd = os.pidfd_open(pid)
    try:
        for entry in Path(f"/proc/{pid}/fd").iterdir():
            target = libc.syscall(438, pidfd, int(entry.name), 0)  # SYS_pidfd_getfd (x86-64 and arm64)
            if target < 0:
                pytest.skip(f"pidfd_getfd is not allowed here (errno {ctypes.get_errno()})")
            try:
                sock = socket.socket(fileno=target)
            except OSError:  # not a socket
                os.close(target)
                continue
            with sock, contextlib.suppress(OSError):  # OSError: not connected (the listener)
                if sock.family == socket.AF_INET and sock.getpeername() == peer:
                    return sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    finally:
        os.close(pidfd)
    raise AssertionError(f"no socket of process {pid} is connected to {peer}")


@pytest.mark.slow
def test_the_servers_connections_send_without_delay() -> None:
    """The running server's end of an API connection has ``TCP_NODELAY`` set."""
    server = LocalServer()
    try:
        server.wait_ready(120)
        assert server._process is not None
        with socket.create_connection(("127.0.0.1", server.port)) as client:
            client.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert client.recv(4096).startswith(b"HTTP/1.1 200")
            assert _peer_socket_option(server._process.pid, client.getsockname()) != 0
    finally:
        server.stop()


def test_the_loopback_ca_file_is_one_certificate_a_tls_context_loads() -> None:
    """What Prefect's clients load for the temporary server (plain HTTP) instead of a 140-certificate
    bundle: a valid CA file (an empty one is an error to ``ssl``), holding one certificate and no key."""
    text = local_server.LOOPBACK_CA.read_text()
    assert text.count("BEGIN CERTIFICATE") == 1
    assert "PRIVATE KEY" not in text
    context = ssl.create_default_context(cafile=str(local_server.LOOPBACK_CA))
    assert context.cert_store_stats()["x509_ca"] == 1


@pytest.mark.slow
def test_the_loopback_ca_file_is_set_for_the_temporary_server_only(
    no_prefect_config: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``launch()`` points Prefect's CA file at the loopback one with the URL, and the server's stop takes
    both away: a caller of ``main()`` whose next run goes to a configured (TLS) server keeps its own
    settings (the variable stayed after the run, seen as a test's leak). A user's own value is kept."""
    for users, expected in (
        (None, str(local_server.LOOPBACK_CA)),
        ("/etc/users-ca.pem", "/etc/users-ca.pem"),
    ):
        if users is None:
            monkeypatch.delenv("PREFECT_API_SSL_CERT_FILE", raising=False)
        else:
            monkeypatch.setenv("PREFECT_API_SSL_CERT_FILE", users)
        monkeypatch.setattr(local_server, "_launched", None)
        server = local_server.launch()
        assert server is not None
        try:
            assert os.environ["PREFECT_API_SSL_CERT_FILE"] == expected
        finally:
            local_server.take_launched()
            server.stop(graceful=False)
        assert os.environ.get("PREFECT_API_SSL_CERT_FILE") == users
        assert "PREFECT_API_URL" not in os.environ


def _post_json(api_url: str, path: str, body: object) -> Any:
    request = urllib.request.Request(
        f"{api_url}{path}", data=json.dumps(body).encode(), headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=30) as response:
        data = response.read()
    return json.loads(data) if data else None


def _test_events(api_url: str, prefix: str) -> list[str]:
    now = datetime.now(UTC)
    window = {"since": (now - timedelta(days=30)).isoformat(), "until": now.isoformat()}
    body = {"filter": {"occurred": window, "event": {"prefix": [prefix]}}, "limit": 50}
    return sorted(e["event"] for e in _post_json(api_url, "/events/filter", body)["events"])


def _until(api_url: str, expected: list[str], prefix: str, timeout_s: float = 30) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while (seen := _test_events(api_url, prefix)) != expected and time.monotonic() < deadline:
        time.sleep(0.5)
    return seen


@pytest.mark.slow
def test_each_start_of_the_temporary_server_prunes_events_past_their_retention() -> None:
    """What docs/operations.md says of ``$PREFECT_HOME/prefect.db``: Prefect's event vacuum runs in the
    temporary server too, once as it starts, so events older than the retention (7 days) do not pile up
    under a job that runs every hour on the embedded default. (The suite's own ``PREFECT_HOME``, whose
    database is migrated already: a new one costs each boot ~10 s more; the events are this test's alone.)"""
    prefix = f"bagport.test.{uuid.uuid4().hex}."
    old, recent = f"{prefix}old", f"{prefix}recent"
    # stored at the event persister's next flush (every 5 s by default)
    settings = {"PREFECT_SERVER_SERVICES_EVENT_PERSISTER_FLUSH_INTERVAL": "0.5"}
    now = datetime.now(UTC)

    def event(name: str, age: timedelta) -> dict[str, Any]:
        occurred = (now - age).isoformat()
        return {
            "id": str(uuid.uuid4()),
            "occurred": occurred,
            "event": name,
            "resource": {"prefect.resource.id": "t"},
        }

    server = LocalServer(settings)
    try:
        server.wait_ready(120)
        _post_json(
            server.api_url, "/events", [event(old, timedelta(days=10)), event(recent, timedelta(hours=1))]
        )
        # both stored: this start's vacuum ran before they came; it runs in the background once the server
        # answers, and on a loaded machine it may come after them, pruning the old one: then it has run, and
        # the old event posted again stays
        seen = _until(server.api_url, [old, recent], prefix, timeout_s=10)
        if seen == [recent]:
            _post_json(server.api_url, "/events", [event(old, timedelta(days=10))])
            seen = _until(server.api_url, [old, recent], prefix)
        assert seen == [old, recent]
    finally:
        server.stop()
    server = LocalServer(settings)
    try:
        server.wait_ready(120)
        assert _until(server.api_url, [recent], prefix) == [recent]
    finally:
        server.stop()
