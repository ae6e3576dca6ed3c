"""`bench/append_history.py` at a tiny scale, so its measurement cannot rot: the plan's read from the table
finds the same bags as from the records, and the history it stands for grows as asked."""

from __future__ import annotations

from pathlib import Path

from bench.append_history import measure


def test_the_history_grows_and_the_table_holds_what_the_records_hold(tmp_path: Path) -> None:
    rows = measure(tmp_path, [2, 5], bags=2)
    assert [(r.runs, r.episodes) for r in rows] == [(2, 4), (5, 10)]
    assert rows[1].records_mb > rows[0].records_mb > 0 and all(r.table_mb > 0 for r in rows)
    assert (tmp_path / "ds/meta/provenance/run-004.json").is_file()
