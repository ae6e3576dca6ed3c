"""The temporary server's SQLite transactions take the write lock at their start (no 503 and 2 s
client retry when two writers meet), and its boot skips the start-up work a settled database does not
need (flows/local_server_app.py)."""

from __future__ import annotations

import asyncio
import shutil
import sqlite3
from pathlib import Path

import pytest
from prefect.server.database.configurations import AioSqliteConfiguration
from sqlalchemy import text

from flows.local_server_app import ImmediateSqliteConfiguration, _head_revisions, settled
from tests.helpers import python_output


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
    assert python_output(probe, tmp_path / "home")[-1] == "ImmediateSqliteConfiguration"


_LIFESPAN_PROBE = """
import asyncio, os, sys
import prefect._internal.plugins.collections as collections
from flows.local_server_app import create_app
app = create_app()
async def main():
    async with app.router.lifespan_context(app):
        print("alembic" in sys.modules, collections._collections is not None, flush=True)
        os._exit(0)
asyncio.run(main())
"""


def _boot(home: Path) -> tuple[bool, bool]:
    """Start the server app's lifespan as uvicorn would (a fresh process on ``home``); whether it ran
    alembic's migrations and whether it loaded Prefect's collections (block-type registration)."""
    words = python_output(_LIFESPAN_PROBE, home, PREFECT__SERVER_EPHEMERAL="1", PREFECT_UI_ENABLED="0")
    migrated, collections = words[-2:]
    return migrated == "True", collections == "True"


def _url(database: Path) -> str:
    return f"sqlite+aiosqlite:///{database}"


@pytest.mark.slow
def test_a_settled_database_boots_without_the_start_up_work(tmp_path: Path) -> None:
    home = tmp_path / "home"
    assert not settled(_url(home / "prefect.db"))  # no database yet
    assert _boot(home) == (True, True)  # created: migrated, block types registered
    assert settled(_url(home / "prefect.db"))
    assert _boot(home) == (False, False)  # nothing to do, and nothing done

    older = tmp_path / "older.db"
    shutil.copy(home / "prefect.db", older)
    with sqlite3.connect(older) as db:
        db.execute("UPDATE alembic_version SET version_num = 'an_older_one'")
    assert not settled(_url(older))  # Prefect migrates it as it always does
    unregistered = tmp_path / "unregistered.db"
    shutil.copy(home / "prefect.db", unregistered)
    with sqlite3.connect(unregistered) as db:
        db.execute("DELETE FROM block_schema")
        db.execute("DELETE FROM block_type")
    assert not settled(_url(unregistered))


def test_a_database_that_is_not_prefects_is_not_settled(tmp_path: Path) -> None:
    (tmp_path / "empty.db").touch()
    sqlite3.connect(tmp_path / "other.db").execute("CREATE TABLE t (x)").connection.close()
    assert not settled(_url(tmp_path / "empty.db"))
    assert not settled(_url(tmp_path / "other.db"))
    assert not settled("sqlite+aiosqlite:///:memory:")


def test_the_head_is_the_migration_nothing_follows(tmp_path: Path) -> None:
    scripts = {
        "a": 'revision = "a1"\ndown_revision = None\n',
        "b": 'revision = "b2"\ndown_revision = "a1"\n',
        "c": "revision: str = 'c3'\ndown_revision: str = 'a1'\n",
        "d": 'revision = "d4"\ndown_revision = ("b2", "c3")\n',  # a merge
    }
    for name, lines in scripts.items():
        (tmp_path / f"{name}.py").write_text(f'"""{name}"""\n{lines}')
    assert _head_revisions(tmp_path) == {"d4"}
    (tmp_path / "d.py").unlink()
    assert _head_revisions(tmp_path) == {"b2", "c3"}
    assert _head_revisions(tmp_path / "nowhere") == set()
