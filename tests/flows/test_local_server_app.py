"""The temporary server's SQLite transactions take the write lock at their start (no 503 and 2 s
client retry when two writers meet), and its boot skips the start-up work a settled database does not
need (flows/local_server_app.py)."""

from __future__ import annotations

import asyncio
import re
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from fastapi import APIRouter, FastAPI
from prefect.server.database.configurations import AioSqliteConfiguration
from sqlalchemy import text
from starlette.routing import Mount

from flows.local_server_app import (
    HOT_PREFIXES,
    ImmediateSqliteConfiguration,
    _head_revisions,
    hot_routers_first,
    settled,
)
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


_COLLECTIONS_PROBE = """
import gc
collections = []
collect = gc.collect
gc.collect = lambda *args: collections.append(args) or collect(*args)
from flows.local_server_app import create_app
create_app()
print(len(collections))
"""


def test_the_server_app_is_built_without_a_whole_heap_collection(tmp_path: Path) -> None:
    """The server's command sets PREFECT__SERVER_FINAL, as Prefect's own ephemeral server does; with this
    FastAPI that only makes Prefect collect the whole heap after the imports (0.29 s of the boot)."""
    words = python_output(
        _COLLECTIONS_PROBE, tmp_path / "home", PREFECT__SERVER_EPHEMERAL="1", PREFECT__SERVER_FINAL="1"
    )
    assert words[-1] == "0"


_HASH_PROBE = """
from prefect.server.api import server
from prefect.settings import Settings, get_current_settings
hashed = []
hash_key = Settings.hash_key
Settings.hash_key = lambda self: hashed.append(1) or hash_key(self)
from flows.local_server_app import create_app
app = create_app()
key = get_current_settings().hash_key()
print(len(hashed) - 1, [k[0] == key for k in server.APP_CACHE], [k[0] == key for k in server.API_APP_CACHE])
"""


def test_the_server_app_hashes_its_settings_once(tmp_path: Path) -> None:
    """Prefect keys two app caches by the settings' hash (every setting serialised, each time): the
    app is built with one, and both caches hold it under the settings' own hash."""
    assert python_output(_HASH_PROBE, tmp_path / "home") == ["1", "[True]", "[True]"]


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


def _api_routes(app: FastAPI) -> list[Any]:
    """The API app's route list (what :func:`hot_routers_first` reorders)."""
    api = next(r for r in app.router.routes if isinstance(r, Mount) and r.path == "/api").app
    routes: list[Any] = getattr(api, "router").routes  # noqa: B009 - a mounted app, typed as any ASGI app
    return routes


def _flat(routes: list[Any]) -> list[Any]:
    """Every route in the order a request is matched against them (an included router's in its place)."""
    flat: list[Any] = []
    for route in routes:
        router = getattr(route, "original_router", None)
        flat.extend(router.routes if router is not None else [route])
    return [r for r in flat if hasattr(r, "path_regex")]


def _concrete(template: str) -> str:
    """A request path for a route's template (its parameters filled in)."""
    path = re.sub(r"\{[^}:]+:uuid\}", "6f3d1f2e-9a3b-4c1d-8e2f-0a1b2c3d4e5f", template)
    path = re.sub(r"\{[^}:]+:path\}", "a/b", path)
    return re.sub(r"\{[^}]+\}", "name", path)


def _served_by(flat: list[Any], path: str, method: str) -> Any:
    return next(
        (r for r in flat if r.path_regex.match(path) and method in (getattr(r, "methods", None) or {method})),
        None,
    )


def _requests(flat: list[Any]) -> list[tuple[str, str]]:
    return [(_concrete(r.path), m) for r in flat for m in sorted(getattr(r, "methods", None) or {"GET"})]


def test_prefects_hot_routers_go_first_and_serve_every_path_as_before(tmp_path: Path) -> None:
    from prefect.server.api.server import create_app as prefect_app  # noqa: PLC0415 - the server's own

    app = prefect_app(ephemeral=True)
    routes = _api_routes(app)
    before = list(routes)
    moved = hot_routers_first(app)
    assert sorted(moved) == sorted(HOT_PREFIXES)  # Prefect's routers keep these prefixes, none blocked
    prefixes = [getattr(getattr(r, "original_router", None), "prefix", None) for r in routes]
    routers = [p for p in prefixes if p is not None]
    assert routers[: len(moved)] == [p for p in prefixes if p in moved]
    assert [getattr(r, "path", None) for r in routes[:6]] == [getattr(r, "path", None) for r in before[:6]]
    requests = _requests(_flat(before))
    assert len(requests) > 150
    for path, method in requests:
        assert _served_by(_flat(routes), path, method) is _served_by(_flat(before), path, method), (
            method,
            path,
        )


def _app_with(*routers: APIRouter) -> FastAPI:
    api = FastAPI()
    for router in routers:
        api.include_router(router)
    app = FastAPI()
    app.mount("/api", api)
    return app


def _router(prefix: str, *paths: str) -> APIRouter:
    router = APIRouter(prefix=prefix)
    for path in paths:
        router.add_api_route(path, lambda: None, methods=["GET"])
    return router


def test_a_router_stays_behind_one_that_could_serve_its_paths() -> None:
    blocking = _app_with(
        _router("/deployments", "/x"), _router("", "/{anything}/version"), _router("/admin", "/version")
    )
    assert hot_routers_first(blocking) == []  # /{anything}/version would no longer see /admin/version
    same_segment = _app_with(
        _router("", "/flows/special"), _router("/flows", "/{name}"), _router("/logs", "/")
    )
    assert hot_routers_first(same_segment) == ["/logs"]  # /flows/{name} would take /flows/special
    routers = [r.original_router.prefix for r in _api_routes(same_segment) if hasattr(r, "original_router")]
    assert routers == ["/logs", "", "/flows"]
