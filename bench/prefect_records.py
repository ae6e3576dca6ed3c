"""What a run wrote to Prefect's API: rows its server added to the SQLite database under ``PREFECT_HOME``.

bagport's temporary server (no ``PREFECT_API_URL``) keeps its records in ``$PREFECT_HOME/prefect.db``, so
counting the rows of a few tables before and after a run gives the flow and task runs it created, their
state changes, log lines and events: a measure of the Prefect API work a run does, taken outside the run
(nothing in the measured processes changes). A run that never starts Prefect (an up-to-date dataset, an
``--append`` with nothing new) adds none; a run against a configured server is not counted here.
"""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

__all__ = ["TABLES", "count_records", "prefect_database", "records_added"]

TABLES = {
    "flow_run": "flow runs",
    "task_run": "task runs",
    "task_run_state": "task states",
    "log": "logs",
    "events": "events",
}
"""Tables counted, with what their rows are."""


def prefect_database() -> Path | None:
    """The SQLite database bagport's temporary server writes to: Prefect's default under ``PREFECT_HOME``;
    ``None`` when the runs go elsewhere (a configured API or database), so nothing is counted."""
    elsewhere = (
        "PREFECT_API_URL",
        "PREFECT_API_DATABASE_CONNECTION_URL",
        "PREFECT_SERVER_DATABASE_CONNECTION_URL",
    )
    if any(os.environ.get(name) for name in elsewhere):
        return None
    home = os.environ.get("PREFECT_HOME") or str(Path.home() / ".prefect")
    return Path(home) / "prefect.db"


def count_records(database: Path) -> dict[str, int]:
    """Rows per table of :data:`TABLES` (zeros when the database or a table does not exist yet)."""
    if not database.exists():
        return dict.fromkeys(TABLES, 0)
    connection = sqlite3.connect(f"file:{database}?mode=ro", uri=True, timeout=30)
    try:
        present = {
            row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
        }
        return {
            table: int(connection.execute(f"SELECT count(*) FROM {table}").fetchone()[0])
            if table in present
            else 0
            for table in TABLES  # a table not created yet: 0; any other error is raised
        }
    finally:
        connection.close()


def records_added(before: dict[str, int], after: dict[str, int]) -> dict[str, int]:
    """Rows added per table between two counts, keyed ``prefect_<table>``."""
    return {f"prefect_{table}": after[table] - before[table] for table in TABLES}
