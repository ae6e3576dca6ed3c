"""A temporary local Prefect server, started before the heavy imports so the two overlap.

Without a configured ``PREFECT_API_URL`` Prefect starts the same server itself (its
``SubprocessASGIServer``), but only once the flow is called: after bagport, Prefect and the
server module are imported in the parent (~4 s) and then the server boots (~5 s), one after
the other. Launching the server process first, with nothing but the standard library, lets it
boot while the CLI imports and plans. The command and environment mirror Prefect's own
(``prefect.server.api.server.SubprocessASGIServer._run_uvicorn_command``); the app is Prefect's, with
its SQLite transactions begun IMMEDIATE (:mod:`flows.local_server_app` says why).

This module imports no Prefect code: ``flows.cli`` calls :func:`launch` before anything heavy.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import os
import socket
import subprocess
import sys
import time
import tomllib
import weakref
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from flows.import_gc import SERVER_PREAMBLE

__all__ = [
    "LIFELINE_ENV",
    "LOOPBACK_CA",
    "LocalServer",
    "ServerStartError",
    "ServerUnreachableError",
    "api_configured",
    "check_reachable",
    "launch",
    "loopback_listener",
    "take_launched",
]


LIFELINE_ENV = "BAGPORT_SERVER_LIFELINE_FD"
"""The temporary server's end of a pipe whose other end only the process that started it holds."""

LOOPBACK_CA = Path(__file__).with_name("loopback-ca.pem")
"""One self-signed certificate (no key exists) that Prefect's clients load for the temporary server.

Prefect builds a TLS context for every API client it creates, loading a CA bundle (certifi's, or the
system's through ``SSL_CERT_FILE``: 140 certificates, 30-60 ms), also for a plain-HTTP server. A W3 run
created 13 clients in each pool worker and 6 in the flow's process: 0.75 s of each worker's 10 s. The
temporary server speaks HTTP on loopback, so no certificate is ever checked; with this one file a context
costs 0.7 ms. ``PREFECT_API_SSL_CERT_FILE`` points at it for runs on the temporary server only (a user's
own value wins in the CLI's environment); a configured server keeps the user's TLS settings."""


class LocalServer:
    """One ``uvicorn`` process serving Prefect's API on a free loopback port."""

    def __init__(self, settings_env: Mapping[str, str] | None = None) -> None:
        """``settings_env``: Prefect settings for the server beyond the environment (a library caller's
        profile or ``temporary_settings``, as Prefect's own ``SubprocessASGIServer`` passes them)."""
        if importlib.util.find_spec("prefect") is None:
            raise RuntimeError("Prefect is not installed")
        listener = loopback_listener()
        self.port = int(listener.getsockname()[1])
        self.api_url = f"http://127.0.0.1:{self.port}/api"
        env = {
            **os.environ,
            **(settings_env or {}),
            "PREFECT_UI_ENABLED": "0",
            "PREFECT__SERVER_EPHEMERAL": "1",
            "PREFECT__SERVER_FINAL": "1",
            # offline, the telemetry service logs a red "Failed to send telemetry" ERROR (and once a
            # "database is locked" traceback) on every run: bagport's own throwaway server sends none
            "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
            # no browser reaches this loopback server (no UI): its clients send no CSRF token (flows/runners.py)
            "PREFECT_SERVER_API_CSRF_PROTECTION_ENABLED": "false",
        }
        env.pop("PREFECT_API_URL", None)
        self._prefect_home = env.get("PREFECT_HOME", "~/.prefect")
        # made with its parents (Prefect makes only the last folder, and warns at its import when it cannot);
        # one that cannot be made is the server's to report (its database is there)
        with contextlib.suppress(OSError):
            Path(self._prefect_home).expanduser().mkdir(parents=True, exist_ok=True)
        # the server's lifeline: it stops when this end closes, also when this process is killed
        # (SIGKILL, the OOM killer) and stop() never runs (flows/local_server_app.py)
        lifeline_r, self._lifeline_w = os.pipe()
        env[LIFELINE_ENV] = str(lifeline_r)
        try:
            self._process: subprocess.Popen[bytes] | None = subprocess.Popen(
                [
                    # uvicorn's own command, with the collector paused through the app's imports (flows/import_gc.py)
                    sys.executable, "-c", f"{SERVER_PREAMBLE}; from uvicorn.main import main; main()",
                    # Prefect's app on SQLite transactions begun IMMEDIATE (flows/local_server_app.py); the
                    # app dir is this package's parent, so a `flows` folder in the working directory is not it
                    "--app-dir", str(Path(__file__).resolve().parent.parent),
                    "--factory", "flows.local_server_app:create_app",
                    "--fd", str(listener.fileno()),
                    "--log-level", "error", "--lifespan", "on",
                ],
                env=env,
                pass_fds=(listener.fileno(), lifeline_r),
            )  # fmt: skip
        finally:
            listener.close()  # the server process holds its own copies
            os.close(lifeline_r)
        atexit.register(self.stop)  # also when the CLI fails before the flow starts
        # a process forked from this one (the CLI's forkserver, its workers) is not the server's owner
        forget = weakref.WeakMethod(self._forget_in_child)

        def after_fork_in_child() -> None:
            method = forget()
            if method is not None:
                method()

        os.register_at_fork(after_in_child=after_fork_in_child)

    def _forget_in_child(self) -> None:
        """In a forked child: close its copy of the lifeline's write end (the server ends with the
        process that started it, not with the last of its forks) and never stop the server from there."""
        if self._process is None:
            return
        self._process = None
        os.close(self._lifeline_w)
        atexit.unregister(self.stop)

    @property
    def pid(self) -> int:
        """The server's process id (while it runs)."""
        if self._process is None:
            raise RuntimeError("the temporary Prefect server was stopped")
        return self._process.pid

    def wait_ready(self, timeout_s: float) -> None:
        """Block until the API answers its health check; raises :class:`ServerStartError` if the server
        exits first or ``timeout_s`` passes."""
        import urllib.error  # noqa: PLC0415 - not before launch(): the server starts first
        import urllib.request  # noqa: PLC0415

        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._process is None or self._process.poll() is not None:
                code = None if self._process is None else self._process.returncode
                raise ServerStartError(
                    f"the temporary Prefect server exited (code {code}) before it was ready (its own message "
                    f"is above); it keeps its database in PREFECT_HOME ({self._prefect_home}): make that a "
                    "folder this user can write, or point PREFECT_API_URL at a running Prefect server"
                )
            try:
                # the listener is bound already: the request waits for the app, however long it boots
                # (with 2 s, a boot of 2.1 s on a busy VM took a retry), and a server that dies resets it
                wait_s = max(0.1, min(10.0, deadline - time.monotonic()))
                with urllib.request.urlopen(f"{self.api_url}/health", timeout=wait_s) as response:
                    if response.status == 200:
                        return
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                pass
            time.sleep(0.1)
        raise ServerStartError(
            f"the temporary Prefect server did not answer within {timeout_s:g} s; "
            "set PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS higher on a slow machine, "
            "or point PREFECT_API_URL at a running server"
        )

    def stop(self, *, graceful: bool = True) -> None:
        """Stop the server and wait for it. ``graceful=False`` kills it at once: for a server nothing used,
        where uvicorn's graceful stop, once it has started, first waits for the app's start-up to finish
        (up to a second after a run that wrote much to its database). SQLite keeps its database whole."""
        if self._process is None:
            return
        if os.environ.get("PREFECT_API_URL") == self.api_url:
            del os.environ["PREFECT_API_URL"]
            # launch() set the CA file with the URL: a later run in this process may go to a TLS server
            if os.environ.get("PREFECT_API_SSL_CERT_FILE") == str(LOOPBACK_CA):
                del os.environ["PREFECT_API_SSL_CERT_FILE"]
        if graceful:
            self._process.terminate()
        else:
            self._process.kill()
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._process = None
        os.close(self._lifeline_w)
        atexit.unregister(self.stop)


def loopback_listener() -> socket.socket:
    """A listening TCP socket on a free loopback port, for the server to take over (``uvicorn --fd``).

    The port is bound here: no other process can take it between choosing it and the server listening
    (a few seconds of imports), and a second run's health check can never reach this one's server.
    ``TCP_NODELAY`` is set here because uvicorn takes an inherited socket as ``AF_UNIX``, so asyncio
    does not set it on the connections it accepts (it does for TCP sockets): Nagle's algorithm then
    held each response split in two writes until the client's delayed ACK, about 40 ms per API call
    (a task run makes several). Linux's accepted connections inherit the option from the listener.
    """
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    listener.bind(("127.0.0.1", 0))
    listener.listen(128)
    return listener


_launched: LocalServer | None = None


class ServerStartError(RuntimeError):
    """The temporary server exited, or did not answer in time, before it was ready (the CLI turns it into
    one paragraph and exit 2)."""


class ServerUnreachableError(RuntimeError):
    """The configured Prefect API does not answer (the CLI turns it into one paragraph and exit 2)."""


def check_reachable(api_url: str, timeout_s: float = 10) -> None:
    """Raise :class:`ServerUnreachableError` unless ``api_url``/health answers."""
    import urllib.error  # noqa: PLC0415 - not imported by launch()'s path
    import urllib.request  # noqa: PLC0415

    try:
        with urllib.request.urlopen(f"{api_url.rstrip('/')}/health", timeout=timeout_s) as response:
            if response.status == 200:
                return
            problem = f"it answered HTTP {response.status}"
    except (urllib.error.URLError, ConnectionError, TimeoutError, ValueError) as err:
        problem = f"{getattr(err, 'reason', err)}"
    raise ServerUnreachableError(
        f"the Prefect server at {api_url} does not answer ({problem}); nothing was converted. "
        "Fix: start it (`prefect server start`, or `make stack` for the whole stack) or correct "
        "PREFECT_API_URL; unset PREFECT_API_URL to let bagport start a temporary server of its own."
    )


def api_configured() -> bool:
    """Whether Prefect has an API URL from the environment, the active profile, or project settings.

    Read without importing Prefect, from the places Prefect reads it: ``PREFECT_API_URL``,
    the active profile in ``profiles.toml``, ``.env``, ``prefect.toml`` and ``pyproject.toml``
    (``[tool.prefect]``) in the working directory.
    """
    if os.environ.get("PREFECT_API_URL"):
        return True
    home = Path(os.environ.get("PREFECT_HOME") or Path.home() / ".prefect")
    profiles_path = Path(os.environ.get("PREFECT_PROFILES_PATH") or home / "profiles.toml")
    try:
        profiles = tomllib.loads(profiles_path.read_text())
    except (OSError, tomllib.TOMLDecodeError):
        profiles = {}
    active = os.environ.get("PREFECT_PROFILE") or profiles.get("active") or "ephemeral"
    if profiles.get("profiles", {}).get(active, {}).get("PREFECT_API_URL"):
        return True
    cwd = Path.cwd()
    dotenv = cwd / ".env"
    if dotenv.is_file() and "PREFECT_API_URL" in dotenv.read_text(errors="replace"):
        return True
    for name, section in (("prefect.toml", ()), ("pyproject.toml", ("tool", "prefect"))):
        try:
            data: Any = tomllib.loads((cwd / name).read_text())
        except (OSError, tomllib.TOMLDecodeError):
            continue
        for key in section:
            data = data.get(key, {}) if isinstance(data, dict) else {}
        if isinstance(data, dict) and isinstance(data.get("api"), dict) and data["api"].get("url"):
            return True
    return False


def launch() -> LocalServer | None:
    """Start the temporary server now and point ``PREFECT_API_URL`` at it, unless an API is configured.

    Call it before Prefect is imported: Prefect snapshots its settings at import, and threads
    without a settings context (its process pool's message forwarder, for one) read that
    snapshot; a URL set later would leave them starting a temporary server of their own.
    """
    global _launched  # noqa: PLW0603 - one temporary server per process
    if _launched is None and not api_configured():
        _launched = LocalServer()
        os.environ["PREFECT_API_URL"] = _launched.api_url
        os.environ.setdefault("PREFECT_API_SSL_CERT_FILE", str(LOOPBACK_CA))  # plain HTTP: never used
        # an offline run with a throwaway server: no SDK telemetry, no "Prefect collects anonymous
        # usage data" notice on the terminal (a user's own DO_NOT_TRACK wins)
        os.environ.setdefault("DO_NOT_TRACK", "1")
    return _launched


def take_launched() -> LocalServer | None:
    """The server :func:`launch` started, handed over to its one user (who stops it)."""
    global _launched
    server, _launched = _launched, None
    return server
