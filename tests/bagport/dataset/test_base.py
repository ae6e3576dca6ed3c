"""An append reads the newest run record's ``files`` digests from its tail only: the same as parsing the
whole record, whatever the episodes hold (nested ``files`` keys, strings that look like the key)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bagport.dataset.base import _record_files
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
    assert _record_files(raw) == json.loads(raw)["files"] == tail["files"]
    assert _record_files(json.dumps({"files": {"a": "b"}}).encode()) == {"a": "b"}  # compact: parsed whole
    assert _record_files(json.dumps({"episodes": []}, indent=2).encode()) is None
