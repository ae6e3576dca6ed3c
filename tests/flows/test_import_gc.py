"""Heavy imports with the cyclic collector paused, and running again after them (flows/import_gc.py)."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from flows.import_gc import SERVER_PREAMBLE, paused


@pytest.fixture
def collector_restored() -> Iterator[None]:
    enabled = gc.isenabled()
    yield
    gc.unfreeze()
    if enabled:
        gc.enable()


def test_paused_through_the_block_then_running_with_the_survivors_frozen(collector_restored: None) -> None:
    gc.unfreeze()
    gc.enable()
    with paused():
        assert not gc.isenabled()
        survivors = [[i] for i in range(1000)]
    assert gc.isenabled()
    assert gc.get_freeze_count() >= len(survivors)


def test_a_paused_collector_stays_paused_after(collector_restored: None) -> None:
    gc.disable()
    with paused():
        pass
    assert not gc.isenabled()


def test_running_again_after_a_failed_import(collector_restored: None) -> None:
    gc.enable()
    with pytest.raises(ImportError), paused():
        import bagport_no_such_module  # type: ignore[import-not-found]  # noqa: F401, PLC0415
    assert gc.isenabled()


def _probe(code: str, tmp_path: Path) -> list[str]:
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "home")}
    env.pop("PREFECT_API_DATABASE_CONNECTION_URL", None)
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, timeout=180
    )
    return done.stdout.split()


def test_the_temporary_server_collects_once_its_app_is_built(tmp_path: Path) -> None:
    """The server's command line pauses the collector (SERVER_PREAMBLE); building the app resumes it."""
    enabled, frozen = _probe(
        f"{SERVER_PREAMBLE}\n"
        "from flows.local_server_app import create_app\n"
        "create_app()\n"
        "print(gc.isenabled(), gc.get_freeze_count() > 100_000)\n",
        tmp_path,
    )
    assert (enabled, frozen) == ("True", "True")


def test_pool_workers_fork_from_a_collecting_forkserver(tmp_path: Path) -> None:
    """What the forkserver imports (flows/worker_preload.py) leaves the collector on, its modules frozen."""
    enabled, frozen = _probe(
        "import gc, flows.worker_preload\nprint(gc.isenabled(), gc.get_freeze_count() > 100_000)\n", tmp_path
    )
    assert (enabled, frozen) == ("True", "True")
