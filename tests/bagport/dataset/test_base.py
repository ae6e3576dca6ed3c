"""An append reads the newest run record's ``files`` digests from its tail only: the same as parsing the
whole record, whatever the episodes hold (nested ``files`` keys, strings that look like the key)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bagport.dataset.base import record_string, record_tail
from bagport.dataset.provenance import write_run_record


def test_the_files_of_a_run_record_come_from_its_tail(tmp_path: Path) -> None:
    record: dict[str, Any] = {"bagport_version": "1.0", "files": {"stale": "00"}, "note": '\n  "files": {}'}
    episodes = [
        {"episode_index": i, "files": {"nested": str(i)}, "text": 'x\n  "files": 1'} for i in range(3)
    ]
    tail = {"files": {"data/chunk-000/file-000.parquet": "ab" * 32}, "files_complete": True}
    path = tmp_path / "run.json"
    write_run_record(path, record, iter(episodes), tail)
    raw = path.read_bytes()
    assert record_tail(raw) == tail
    assert record_tail(raw)["files"] == json.loads(raw)["files"]
    assert record_tail(json.dumps({"files": {"a": "b"}}).encode()) == {"files": {"a": "b"}}  # parsed whole
    assert record_tail(json.dumps({"episodes": []}, indent=2).encode()) == {}


def test_a_top_level_string_of_a_run_record_is_read_from_its_own_line(tmp_path: Path) -> None:
    record: dict[str, Any] = {"note": 'a\n  "write_key": "forged"', "write_key": "k" * 64, "count": 3}
    episodes = [{"episode_index": i, "write_key": f"episode-{i}"} for i in range(3)]
    path = tmp_path / "run.json"
    write_run_record(path, record, iter(episodes), {"files": {}, "files_complete": True})
    raw = path.read_bytes()
    assert record_string(raw, "write_key") == json.loads(raw)["write_key"] == "k" * 64
    assert record_string(raw, "count") is None  # not a string
    assert record_string(raw, "missing") is None
