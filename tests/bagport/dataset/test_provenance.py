"""The run record is streamed one episode at a time, byte for byte what ``json.dumps(indent=2)`` writes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from bagport.dataset.provenance import write_run_record


@pytest.mark.parametrize("count", [0, 1, 3])
def test_the_streamed_run_record_equals_json_dumps(tmp_path: Path, count: int) -> None:
    record: dict[str, Any] = {
        "bagport_version": "1.0",
        "contract": {"uri": "c.yaml", "text": "a: 1\nb: [1, 2]\n"},
        "manifest": {"bags": ["a", "b"], "reused": [], "empty": {}},
        "host_cpus": 2,
        "path": Path("/x"),  # not JSON: written as its str, as json.dumps(default=str) does
    }
    episodes = [
        {"episode_index": i, "alignment": [{"ms": 0.5 * i, "ok": True}], "metadata": {}} for i in range(count)
    ]
    tail = {"files": {"data/a.parquet": "00ff"}, "files_complete": True}
    path = tmp_path / "run.json"
    write_run_record(path, record, iter(episodes), tail)
    assert path.read_text() == json.dumps({**record, "episodes": episodes, **tail}, indent=2, default=str)
