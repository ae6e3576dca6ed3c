"""The app bagport's temporary Prefect server serves: Prefect's own, its SQLite transactions begun IMMEDIATE.

Prefect begins a SQLite transaction DEFERRED: it reads, and takes the write lock only at its first
write. The task engine checks tag concurrency limits once per task run with tags
(``POST /v2/concurrency_limits/increment-with-lease``): a read, then an ``UPDATE`` even when no limit
exists. When another request (a log batch, a state, an event) commits between the two, SQLite refuses
the upgrade at once (``SQLITE_BUSY_SNAPSHOT``: its busy timeout does not apply), the server answers
503 and Prefect's client sleeps 2 s before it tries again, while the worker sits idle. On W3 (200
two-second episodes, 17 task runs) 5-9 task runs in a run waited so, about 9 s of its 30 s.

``BEGIN IMMEDIATE`` takes the write lock first, so a second writer waits on SQLite's busy timeout
(60 s in Prefect) for the milliseconds the first one holds it instead of failing: the cure Prefect's own
comment in ``AioSqliteConfiguration.setup_sqlite`` names (upstream: PrefectHQ/prefect#18934). It is set
through Prefect's own injection point (``set_database_config``), for bagport's temporary server only;
a server the user runs (``PREFECT_API_URL``, PostgreSQL in ``make stack``) is theirs and untouched.

On a database that needs none of it, the server also skips the start-up work Prefect's lifespan does
on every boot (:func:`settled`): ``alembic upgrade`` (importing alembic and reading every migration, to
find nothing to do) and block-type registration (which imports every installed collection, Dask's
``distributed`` with ``prefect-dask``, only to hash them and skip). About 0.5 s of the server's boot,
which every run without ``PREFECT_API_URL`` waits for.

Its API's routers are reordered (:func:`hot_routers_first`): those a conversion run calls come first, as
the first request waits while FastAPI builds the route state of every router tried before its own. Its
settings are hashed once while the app is built (:func:`hashed_once`), not once per app cache.

This module runs in the server's process (``uvicorn --factory flows.local_server_app:create_app``).
"""

from __future__ import annotations

import os
import re
import signal
import sqlite3
from collections.abc import AsyncGenerator, Iterator
from contextlib import asynccontextmanager, closing, contextmanager
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING

import prefect.server.database
from prefect.context import refresh_global_settings_context
from prefect.server.database.configurations import AioSqliteConfiguration
from prefect.server.database.dependencies import set_database_config
from prefect.server.utilities.database import get_dialect
from prefect.settings import PREFECT_API_DATABASE_CONNECTION_URL, Settings
from sqlalchemy.engine import make_url
from starlette.routing import Mount

from flows.import_gc import resume
from flows.lifeline import when_cut
from flows.local_server import LIFELINE_ENV

if TYPE_CHECKING:
    from fastapi import FastAPI
    from sqlalchemy.ext.asyncio import AsyncSession, AsyncSessionTransaction

__all__ = [
    "HOT_PREFIXES",
    "ImmediateSqliteConfiguration",
    "create_app",
    "hashed_once",
    "hot_routers_first",
    "settled",
]


class ImmediateSqliteConfiguration(AioSqliteConfiguration):
    """Prefect's SQLite configuration whose every transaction begins ``IMMEDIATE`` (holds the write
    lock from its start), so concurrent writers queue on the busy timeout instead of answering 503."""

    @asynccontextmanager
    async def begin_transaction(
        self,
        session: AsyncSession,
        with_for_update: bool = False,  # noqa: ARG002 - every transaction is begun as if it were
    ) -> AsyncGenerator[AsyncSessionTransaction, None]:
        async with super().begin_transaction(session, with_for_update=True) as transaction:
            yield transaction


def _stop_when_orphaned() -> None:
    """Stop this server (as ``LocalServer.stop`` would: SIGTERM) when the process that started it is
    gone, also when that process was killed and never stopped the server (:mod:`flows.lifeline`)."""
    lifeline = os.environ.get(LIFELINE_ENV)
    if lifeline is not None:
        when_cut(Connection(int(lifeline), writable=False), lambda: os.kill(os.getpid(), signal.SIGTERM))


SETTLED_SKIPS = {
    "PREFECT_API_DATABASE_MIGRATE_ON_START": "false",
    "PREFECT_API_BLOCKS_REGISTER_ON_START": "false",
    # with memoizing on, Prefect imports every collection to hash the block registry before it skips
    "PREFECT_MEMOIZE_BLOCK_AUTO_REGISTRATION": "false",
}
"""The settings that turn the lifespan's start-up work off, for a database :func:`settled` says needs none."""

_REVISION_LINE = re.compile(r"^(revision|down_revision)\s*(?::[^=]*)?=\s*(.+)$", re.MULTILINE)


def _head_revisions(versions_dir: Path) -> set[str]:
    """The migrations no other migration follows: what ``alembic upgrade head`` would bring a database to.

    Read from the migration files' ``revision``/``down_revision`` lines (a merge names several parents),
    without importing alembic. Nothing found (a layout this code does not know) means no head.
    """
    revisions: set[str] = set()
    parents: set[str] = set()
    for script in versions_dir.glob("*.py"):
        for name, value in _REVISION_LINE.findall(script.read_text(encoding="utf-8")):
            ids = set(re.findall(r"[\"']([0-9A-Za-z_]+)[\"']", value))
            (revisions if name == "revision" else parents).update(ids)
    return revisions - parents


def settled(connection_url: str) -> bool:
    """Whether the SQLite database at ``connection_url`` is at this Prefect's newest migration and has its
    block types registered (by an earlier boot), so a boot has nothing to create, migrate or register.

    Anything else (no file yet, an older or newer schema, a database this cannot read) answers ``False``
    and Prefect does its start-up work as it always does.
    """
    database = make_url(connection_url).database
    if not database or database == ":memory:" or not Path(database).is_file():
        return False
    versions_dir = Path(prefect.server.database.__file__).parent / "_migrations" / "versions" / "sqlite"
    heads = _head_revisions(versions_dir)
    try:
        with closing(sqlite3.connect(f"file:{database}?mode=ro", uri=True, timeout=5)) as db:
            versions = {row[0] for row in db.execute("SELECT version_num FROM alembic_version")}
            (block_types,) = db.execute("SELECT count(*) FROM block_type").fetchone()
    except sqlite3.Error:
        return False
    return bool(heads) and versions == heads and block_types > 0


HOT_PREFIXES = (
    "/admin", "/csrf-token", "/flows", "/flow_runs", "/task_runs", "/logs", "/v2/concurrency_limits",
    "/artifacts", "/events",
)  # fmt: skip
"""The prefixes of the API's routers a conversion run calls (the client's version check, the flow run,
its artifacts and logs, the task runs' tag leases and events)."""


def _first_segment(path: str) -> str:
    return path.lstrip("/").split("/", 1)[0]


def hot_routers_first(app: FastAPI) -> list[str]:
    """Move the API's routers with a :data:`HOT_PREFIXES` prefix ahead of the others; the prefixes moved.

    FastAPI (0.150) builds a router's route state (dependencies, parameters) the first time a request is
    matched against it, and tries the routers in order: the run's first call (``GET /admin/version``,
    Prefect's client checking the server) came after 27 routers and waited 0.16 s while 180 routes were
    built, on the path from the server's start to the flow's. First, only the run's own ~60 are.

    A router moves only when no router it passes could serve one of its paths (a route whose first path
    segment is its own or a path parameter), so every request is served by the same route as before.
    """
    api = next((r.app for r in app.router.routes if isinstance(r, Mount) and r.path == "/api"), None)
    routes = getattr(getattr(api, "router", None), "routes", None)
    if not isinstance(routes, list):
        return []
    moved: list[str] = []
    passed: set[str] = set()  # the first path segments of the routes a moved router would go ahead of
    for route in routes:
        router = getattr(route, "original_router", None)
        prefix = getattr(router, "prefix", None)
        if (
            prefix in HOT_PREFIXES
            and not passed & {_first_segment(prefix)}
            and not any(segment.startswith("{") for segment in passed)
        ):
            moved.append(prefix)
            continue
        paths = [str(getattr(r, "path", "")) for r in getattr(router, "routes", [])]
        passed.update(_first_segment(path) for path in paths or [str(getattr(route, "path", ""))])
    hot = [r for r in routes if getattr(getattr(r, "original_router", None), "prefix", None) in moved]
    rest = [r for r in routes if not any(r is h for h in hot)]
    at = next((i for i, r in enumerate(rest) if hasattr(r, "original_router")), len(rest))
    routes[:] = rest[:at] + hot + rest[at:]  # after the plain routes (the health check's among them)
    return moved


@contextmanager
def hashed_once() -> Iterator[None]:
    """Prefect's settings hashed once per settings object while the block runs.

    Prefect's ``create_app`` and ``create_api_app`` each key an app cache by ``Settings.hash_key()``,
    which serialises every setting (0.05-0.15 s each, a sixth to a quarter of building the app on the
    path to the server's first answer); in this process both caches are empty and the settings are the
    same object, so the second hash is the first one again.
    """
    original = Settings.hash_key
    hashes: dict[int, tuple[Settings, str]] = {}  # by id, the object held so its id is not reused

    def hash_key(settings: Settings) -> str:
        if id(settings) not in hashes:
            hashes[id(settings)] = (settings, original(settings))
        return hashes[id(settings)][1]

    Settings.hash_key = hash_key  # type: ignore[method-assign,assignment]
    try:
        yield
    finally:
        Settings.hash_key = original  # type: ignore[method-assign]


def _make_database_folder(connection_url: str) -> None:
    """The SQLite database's folder (``PREFECT_HOME`` by default), made when missing: SQLite creates the
    file, not its folder, and the server would exit on "unable to open database file" with a traceback.
    A folder that cannot be made is one line on stderr and exit code 1 (the CLI says what to do)."""
    database = make_url(connection_url).database
    if not database or database == ":memory:":
        return
    folder = Path(database).expanduser().parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SystemExit(
            f"the temporary Prefect server cannot make its database's folder {folder}: {err}"
        ) from None


def create_app() -> FastAPI:
    """Prefect's API app, on :class:`ImmediateSqliteConfiguration` when its database is SQLite, without
    the start-up work a :func:`settled` database does not need."""
    import prefect.server.api.server as prefect_server  # noqa: PLC0415 - after the config
    from prefect.server.api.server import create_app as prefect_app  # noqa: PLC0415 - after the config

    _stop_when_orphaned()

    connection_url = PREFECT_API_DATABASE_CONNECTION_URL.value()
    if get_dialect(connection_url).name == "sqlite":
        _make_database_folder(connection_url)
        set_database_config(ImmediateSqliteConfiguration(connection_url=connection_url))
        if settled(connection_url):
            os.environ.update(SETTLED_SKIPS)  # this process is the server's own: nothing else reads them
            refresh_global_settings_context()
    if not getattr(prefect_server, "_FASTAPI_COPIES_ROUTES_ON_INCLUDE", True):
        # "final" (set as Prefect's own ephemeral server sets it) deletes the routers' copies where FastAPI
        # copies them (< 0.137), then collects the whole heap: with this FastAPI there are no copies, and
        # the collection walks every object the imports made (the collector is paused through them,
        # flows/import_gc.py), 0.29 s of the boot the run waits for, to free nothing (the same peak RSS)
        os.environ.pop("PREFECT__SERVER_FINAL", None)
    with hashed_once():
        app = prefect_app()
    hot_routers_first(app)
    resume()  # the collector, paused by the server's command line through these imports (flows/import_gc.py)
    return app
