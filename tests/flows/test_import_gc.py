"""Heavy imports with the cyclic collector paused, and running again after them (flows/import_gc.py)."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from pathlib import Path

import pytest

from flows.import_gc import SERVER_PREAMBLE, paused
from tests.helpers import python_output


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


def test_the_temporary_server_collects_once_its_app_is_built(tmp_path: Path) -> None:
    """The server's command line pauses the collector (SERVER_PREAMBLE); building the app resumes it."""
    enabled, frozen = python_output(
        f"{SERVER_PREAMBLE}\n"
        "from flows.local_server_app import create_app\n"
        "create_app()\n"
        "print(gc.isenabled(), gc.get_freeze_count() > 100_000)\n",
        tmp_path / "home",
    )
    assert (enabled, frozen) == ("True", "True")


def test_pool_workers_fork_from_a_collecting_forkserver(tmp_path: Path) -> None:
    """What the forkserver imports (flows/worker_preload.py) leaves the collector on, its modules frozen."""
    enabled, frozen = python_output(
        "import gc, flows.worker_preload\nprint(gc.isenabled(), gc.get_freeze_count() > 100_000)\n",
        tmp_path / "home",
    )
    assert (enabled, frozen) == ("True", "True")
