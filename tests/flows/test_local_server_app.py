"""The temporary server's SQLite transactions take the write lock at their start (no 503 and 2 s
client retry when two writers meet: flows/local_server_app.py)."""

from __future__ import annotations

import asyncio
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from prefect.server.database.configurations import AioSqliteConfiguration
from sqlalchemy import text

from flows.local_server_app import ImmediateSqliteConfiguration


def _second_writer_waits(config_type: type[AioSqliteConfiguration], path: Path) -> bool:
    """Whether, inside a transaction of ``config_type`` that has only read so far, another connection
    is kept from taking the write lock."""

    async def probe() -> bool:
        config = config_type(connection_url=f"sqlite+aiosqlite:///{path}")
        engine = await config.engine()
        try:
            session = await config.session(engine)
            async with session, config.begin_transaction(session):
                await session.execute(text("SELECT 1"))
                other = sqlite3.connect(path, timeout=0, isolation_level=None)
                try:
                    other.execute("BEGIN IMMEDIATE")
                except sqlite3.OperationalError as err:
                    assert "locked" in str(err)
                    return True
                finally:
                    other.close()
                return False
        finally:
            await engine.dispose()

    return asyncio.run(probe())


def test_a_transaction_holds_the_write_lock_from_its_start(tmp_path: Path) -> None:
    assert _second_writer_waits(ImmediateSqliteConfiguration, tmp_path / "immediate.db")


def test_prefects_own_configuration_does_not(tmp_path: Path) -> None:
    """The contrast that makes the test above mean something: Prefect begins DEFERRED, so a read-only
    start leaves the write lock free and a later upgrade can fail with SQLITE_BUSY_SNAPSHOT."""
    assert not _second_writer_waits(AioSqliteConfiguration, tmp_path / "deferred.db")


@pytest.mark.slow
def test_the_server_app_is_bagports_even_beside_a_flows_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """uvicorn puts its --app-dir first on sys.path: a user's own ``flows`` package in the working
    directory must not shadow bagport's."""
    from flows.local_server import LocalServer  # noqa: PLC0415 - the module under test

    (tmp_path / "flows").mkdir()
    (tmp_path / "flows" / "__init__.py").write_text("raise ImportError('the user project flows package')\n")
    monkeypatch.chdir(tmp_path)
    server = LocalServer()
    try:
        server.wait_ready(120)
    finally:
        server.stop()


def test_the_server_app_runs_on_the_immediate_configuration(tmp_path: Path) -> None:
    """What uvicorn's factory call sets up (in a fresh process: the configuration is process-wide)."""
    probe = (
        "from flows.local_server_app import create_app\n"
        "from prefect.server.database.dependencies import provide_database_interface\n"
        "create_app()\n"
        "print(type(provide_database_interface().database_config).__name__)\n"
    )
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "home")}
    env.pop("PREFECT_API_DATABASE_CONNECTION_URL", None)
    done = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True, timeout=120
    )
    assert done.stdout.split()[-1] == "ImmediateSqliteConfiguration"
