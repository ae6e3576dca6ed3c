"""CSV manifests: the same entries as YAML (uri, task, windows, every other column as metadata), errors
by row and column; a CSV manifest and its YAML twin give identical datasets, robot_id reaches QA."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from bagport.errors import ManifestError
from bagport.manifest import load_manifest
from bagport.synth import EpisodeSpec, write_episode_bag
from bagport.timewindow import TimeWindow
from tests.helpers import SAMPLE_CONTRACT, convert_in_process


def _touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x")
    return path


def test_columns_become_entries_and_metadata(tmp_path: Path) -> None:
    _touch(tmp_path / "bags/a.mcap")
    _touch(tmp_path / "bags/b.mcap")
    manifest = tmp_path / "fleet.csv"
    manifest.write_text(
        "uri,task,robot_id,collection_date,start_s,end_s\n"
        "bags/a.mcap,fold the towel,arm-07,2026-11-02,,\n"
        "\n"
        'bags/b.mcap,"pick, then place",arm-09,2026-11-03,1.5,4\n'
    )
    loaded = load_manifest(str(manifest))
    assert [(Path(b.uri).name, b.entry, b.task, b.window) for b in loaded.bags] == [
        ("a.mcap", 0, "fold the towel", TimeWindow()),
        ("b.mcap", 1, "pick, then place", TimeWindow(start_s=1.5, end_s=4.0)),
    ]
    assert loaded.bags[1].metadata == {"robot_id": "arm-09", "collection_date": "2026-11-03"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param(
            "uri,robot_id\nbags/a.mcap,arm-1\nbags/nope.mcap,arm-2\n",
            "m.csv, row 3 (column uri): bag '{root}/bags/nope.mcap' does not exist Fix: fix the path (relative "
            "paths are relative to the manifest file) or remove the entry.",
            id="missing-bag",
        ),
        pytest.param(
            "uri,start_s,end_s\nbags/a.mcap,soon,3\n",
            "m.csv, row 2 (column start_s): Input should be a valid number, unable to parse string as a number "
            "(cell 'soon') Fix: fix the cell; start_s/end_s are seconds from the bag's first message, uri is "
            "required.",
            id="bad-number",
        ),
        pytest.param(
            "uri,start_s,end_s\nbags/a.mcap,5,3\n",
            "m.csv, row 2 (column end_s): the window ends (end_s 3.0) at or before it starts (start_s 5.0) Fix: "
            "give an end_s greater than start_s, or leave one of them out (the bag's start or end).",
            id="window",
        ),
        pytest.param(
            "uri,start_ns,task,start_s\nbags/a.mcap,5,t,1\n",
            "m.csv, row 2 (column start_s): gives both start_s (seconds from the bag's first message) and start_ns "
            "(ROS time) Fix: keep one of the two: remove start_s or start_ns.",
            id="two-starts",
        ),
        pytest.param(
            "path,robot_id\nbags/a.mcap,arm-1\n",
            "m.csv, row 1: the header row has no 'uri' column (columns: path, robot_id) Fix: a CSV manifest is a "
            "header row (uri, and optionally task, start_s, end_s, any metadata columns) and one row per bag.",
            id="no-uri-column",
        ),
        pytest.param(
            "uri,robot_id\nbags/a.mcap,arm-1\n,arm-2\n",
            "m.csv, row 3 (column uri): Field required Fix: fix the cell; start_s/end_s are seconds from the bag's "
            "first message, uri is required.",
            id="empty-uri",
        ),
        pytest.param(
            "uri,robot_id\nbags/a.mcap,arm-1,extra\n",
            "m.csv, row 2: has 3 cells, the header names 2 columns Fix: quote cells that contain commas, or add "
            "the missing column to the header.",
            id="extra-cell",
        ),
        pytest.param(
            "uri,robot_id\nbags/a.mcap,arm-1\nbags/a.mcap,arm-1\n",
            "m.csv, row 3 (column uri): bag '{root}/bags/a.mcap' is listed twice (also row 2) Fix: remove the "
            "duplicate; one bag (or one window of it: start_s/end_s) is one episode.",
            id="duplicate",
        ),
    ],
)
def test_errors_name_the_row_and_column(tmp_path: Path, text: str, message: str) -> None:
    _touch(tmp_path / "bags/a.mcap")
    manifest = tmp_path / "m.csv"
    manifest.write_text(text)
    with pytest.raises(ManifestError) as caught:
        load_manifest(str(manifest))
    assert str(caught.value) == f"{manifest.parent}/" + message.format(root=tmp_path)


def test_csv_and_yaml_manifests_give_identical_datasets(tmp_path: Path) -> None:
    for name, seed in (("ep_a", 1), ("ep_b", 2)):
        write_episode_bag(tmp_path / "bags" / name, "mcap", EpisodeSpec(duration_s=1.5, seed=seed))
    (tmp_path / "fleet.csv").write_text(
        "uri,task,robot_id,collection_date\n"
        "bags/ep_a,fold the towel,arm-07,2026-11-02\n"
        "bags/ep_b,stack the cups,arm-09,2026-11-03\n"
    )
    (tmp_path / "fleet.yaml").write_text(
        "bags:\n"
        "  - {uri: bags/ep_a, task: fold the towel, metadata: {robot_id: arm-07, collection_date: '2026-11-02'}}\n"
        "  - {uri: bags/ep_b, task: stack the cups, metadata: {robot_id: arm-09, collection_date: '2026-11-03'}}\n"
    )
    contract = SAMPLE_CONTRACT.read_text()
    outs = {}
    for kind in ("csv", "yaml"):
        work = tmp_path / kind
        work.mkdir()
        outs[kind] = convert_in_process(str(tmp_path / f"fleet.{kind}"), contract, work, repo_id="test/fleet")
    csv_out, yaml_out = outs["csv"], outs["yaml"]
    data = sorted(p.relative_to(csv_out) for p in csv_out.glob("data/**/*.parquet"))
    assert data and data == sorted(p.relative_to(yaml_out) for p in yaml_out.glob("data/**/*.parquet"))
    for relative in data:
        assert pq.read_table(csv_out / relative).equals(pq.read_table(yaml_out / relative))
    assert (csv_out / "meta/info.json").read_text() == (yaml_out / "meta/info.json").read_text()
    assert (csv_out / "meta/tasks.parquet").read_bytes() == (yaml_out / "meta/tasks.parquet").read_bytes()
    for out in (csv_out, yaml_out):
        episodes = json.loads((out / "meta/provenance/run.json").read_text())["episodes"]
        assert [e["metadata"] for e in episodes] == [
            {"robot_id": "arm-07", "collection_date": "2026-11-02"},
            {"robot_id": "arm-09", "collection_date": "2026-11-03"},
        ]
        rows = pq.read_table(out / "meta/qa/chunk-000/file-000.parquet").to_pylist()
        assert {(r["episode_index"], r["robot_id"]) for r in rows} == {(0, "arm-07"), (1, "arm-09")}
