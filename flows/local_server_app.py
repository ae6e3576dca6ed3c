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

This module runs in the server's process (``uvicorn --factory flows.local_server_app:create_app``).
"""

from __future__ import annotations

import os
import signal
from collections.abc import AsyncGenerator
from contextlib import asynccontextmanager
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING

from prefect.server.database.configurations import AioSqliteConfiguration
from prefect.server.database.dependencies import set_database_config
from prefect.server.utilities.database import get_dialect
from prefect.settings import PREFECT_API_DATABASE_CONNECTION_URL

from flows.lifeline import when_cut
from flows.local_server import LIFELINE_ENV

if TYPE_CHECKING:
    from fastapi import FastAPI
    from sqlalchemy.ext.asyncio import AsyncSession, AsyncSessionTransaction

__all__ = ["ImmediateSqliteConfiguration", "create_app"]


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


def create_app() -> FastAPI:
    """Prefect's API app, on :class:`ImmediateSqliteConfiguration` when its database is SQLite."""
    from prefect.server.api.server import create_app as prefect_app  # noqa: PLC0415 - after the config

    _stop_when_orphaned()

    connection_url = PREFECT_API_DATABASE_CONNECTION_URL.value()
    if get_dialect(connection_url).name == "sqlite":
        set_database_config(ImmediateSqliteConfiguration(connection_url=connection_url))
    return prefect_app()
