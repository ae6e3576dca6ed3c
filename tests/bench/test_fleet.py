"""W4 at a tiny scale through the harness (`bench/fleet.py`), so its phases and table cannot rot, and the
Prefect records each phase writes (`bench/prefect_records.py`) are counted from the real server's database."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from bench.prefect_records import TABLES, count_records, records_added
from tests.conftest import REPO


def test_records_are_counted_per_table_and_zero_before_the_database_exists(tmp_path: Path) -> None:
    database = tmp_path / "prefect.db"
    assert count_records(database) == dict.fromkeys(TABLES, 0)
    connection = sqlite3.connect(database)
    connection.execute("CREATE TABLE task_run (id TEXT)")
    connection.executemany("INSERT INTO task_run VALUES (?)", [("a",), ("b",)])
    connection.commit()
    before = count_records(database)
    assert before["task_run"] == 2 and before["log"] == 0  # a table not created yet counts 0
    connection.execute("INSERT INTO task_run VALUES ('c')")
    connection.commit()
    connection.close()
    added = records_added(before, count_records(database))
    assert added["prefect_task_run"] == 1 and added["prefect_events"] == 0


@pytest.mark.slow
def test_the_fleet_phases_run_and_report_what_they_wrote_to_prefect(tmp_path: Path) -> None:
    report, results = tmp_path / "BENCHMARKS.md", tmp_path / "results.json"
    report.write_text(
        "<!-- results:start -->\n<!-- results:end -->\n<!-- fleet:start -->\nold\n<!-- fleet:end -->\n"
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PREFECT_HOME": str(tmp_path / "prefect")}
    env.pop("PREFECT_API_URL", None)
    done = subprocess.run(
        [sys.executable, str(REPO / "bench" / "run.py"), "--workloads", "W4", "--scale", "0.001", "--runs", "1",
         "--data", str(tmp_path / "data"), "--report", str(report), "--results", str(results)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    fleet = json.loads(results.read_text())["workloads"]["W4"]["fleet"]
    assert list(fleet) == [
        "first 2", "first", "no-op re-run", "no-op append", "no-op re-run 2", "staged, new output 2",
        "touched re-run (20 bags)",
    ]  # fmt: skip
    first = fleet["first"]
    assert first["prefect_flow_run"] == 1 and first["prefect_task_run"] >= 2  # 2 bags, then the file writes
    assert first["prefect_task_run_state"] >= 2 * first["prefect_task_run"] and first["prefect_events"] > 0
    # an up-to-date dataset and an --append with nothing new end before Prefect starts: nothing recorded
    for name in ("no-op re-run", "no-op append", "no-op re-run 2"):
        assert all(fleet[name][f"prefect_{table}"] == 0 for table in TABLES), (name, fleet[name])
    # the touched bags convert again; the staged-only run writes files but converts nothing
    assert fleet["touched re-run (20 bags)"]["prefect_flow_run"] == 1
    text = report.read_text()
    assert "old" not in text and "| Prefect records written |" in text
    assert "| first | " in text and "1 flow runs" in text
