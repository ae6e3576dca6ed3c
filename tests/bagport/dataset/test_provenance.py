"""The run record is streamed one episode at a time, byte for byte what ``json.dumps(indent=2)`` writes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from bagport.dataset.provenance import episode_provenance, write_run_record
from bagport.episode import convert_episode
from bagport.errors import DatasetWriteError
from bagport.staging import read_summary
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import episode_request


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


def test_a_lean_summary_whose_staged_episode_is_gone_is_an_error_not_an_empty_entry(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3, seed=1))
    outcome = convert_episode(episode_request(tmp_path / "ep", tmp_path / "staging"))
    summary = read_summary(outcome.dir_uri)
    assert summary is not None and summary.qa
    lean = replace(summary, alignment=[], qa={})  # as the reduce holds it
    assert episode_provenance(lean, 0)["qa"] == summary.qa  # read back from the staged episode
    with pytest.raises(DatasetWriteError, match=r"is gone or its episode\.json unreadable since this run"):
        episode_provenance(replace(lean, dir_uri=str(tmp_path / "gone")), 0)
