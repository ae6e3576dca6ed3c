"""meta/qa across runs: an append writes its own table, index and detail pages, reads none of the old
runs' checks or pages (only their compact index), and the summary and report cover every run; a dataset
written before the index existed is migrated from its summary.json once."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq

from bagport.dataset.qa import QA_INDEX_PATH, QA_REPORT_PATH, QA_SUMMARY_PATH, write_qa
from bagport.synth.qa_entries import synth_qa_entries
from tests.fswatch import watch_reads


def test_an_append_reads_only_the_index_of_earlier_runs(tmp_path: Path) -> None:
    first, second = synth_qa_entries(300, seed=1), synth_qa_entries(40, seed=2)
    write_qa(tmp_path, first, {"fps": 30}, {}, 0, robot_type="arm")
    earlier = sorted(p for p in (tmp_path / "meta/qa").rglob("*") if p.is_file() and "index" not in p.parts)
    assert any("details" in p.parts for p in earlier)
    before = {p: p.read_bytes() for p in earlier if p.name not in ("summary.json", "report.html")}
    with watch_reads(list(before)) as touched:  # (the summary and report are rewritten: opened to write)
        assert write_qa(tmp_path, second, {"fps": 30}, {}, 1, robot_type="arm") == QA_REPORT_PATH
    assert not touched, sorted(map(str, touched))
    assert {p: p.read_bytes() for p in before} == before
    summary = json.loads((tmp_path / QA_SUMMARY_PATH).read_text())
    assert len(summary["episodes"]) == 340
    assert [e["bag_uri"] for e in summary["episodes"]] == [e.qa.bag_uri for e in first + second]
    assert pq.read_table(tmp_path / QA_INDEX_PATH.format(run=1)).num_rows == 40
    assert "340 episode(s) over 2 run(s)" in (tmp_path / QA_REPORT_PATH).read_text()


def test_a_dataset_without_index_is_migrated_from_its_summary_once(tmp_path: Path) -> None:
    write_qa(tmp_path, synth_qa_entries(20, seed=1), {"fps": 30}, {}, 0)
    (tmp_path / QA_INDEX_PATH.format(run=0)).unlink()  # as written by an older bagport
    write_qa(tmp_path, synth_qa_entries(5, seed=2), {"fps": 30}, {}, 1)
    write_qa(tmp_path, synth_qa_entries(3, seed=3), {"fps": 30}, {}, 2)
    summary = json.loads((tmp_path / QA_SUMMARY_PATH).read_text())
    assert len(summary["episodes"]) == 28  # every run once: the legacy rows are not read twice
    assert pq.read_table(tmp_path / QA_INDEX_PATH.format(run=0)).num_rows == 20


def test_the_summary_lists_each_episodes_metadata_across_runs(tmp_path: Path) -> None:
    """The manifest's columns (robot_id...) of every episode, kept or excluded, in summary.json: from this
    run's index, an earlier run's, a legacy summary migrated, and an index written before the column (none)."""
    first = [
        replace(e, metadata={"robot_id": f"r{n}", "collection_date": "2026-11-01"})
        for n, e in enumerate(synth_qa_entries(3, seed=1))
    ]
    write_qa(tmp_path, first, {"fps": 30}, {}, 0)
    summary = json.loads((tmp_path / QA_SUMMARY_PATH).read_text())
    assert [e["metadata"] for e in summary["episodes"]] == [e.metadata for e in first]
    (
        tmp_path / QA_INDEX_PATH.format(run=0)
    ).unlink()  # as an older bagport wrote it: migrated from summary.json
    write_qa(
        tmp_path,
        [replace(e, metadata={"robot_id": "r9"}) for e in synth_qa_entries(1, seed=2)],
        {"fps": 30},
        {},
        1,
    )
    summary = json.loads((tmp_path / QA_SUMMARY_PATH).read_text())
    assert [e["metadata"] for e in summary["episodes"]] == [*(e.metadata for e in first), {"robot_id": "r9"}]
    index = tmp_path / QA_INDEX_PATH.format(run=1)  # an index from before the metadata column
    pq.write_table(pq.read_table(index).drop_columns(["metadata"]), index)
    write_qa(tmp_path, synth_qa_entries(1, seed=3), {"fps": 30}, {}, 2)
    summary = json.loads((tmp_path / QA_SUMMARY_PATH).read_text())
    assert [e["metadata"] for e in summary["episodes"]][3:] == [{}, {}]
