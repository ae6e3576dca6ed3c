"""Staged files read back as they were written."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import fsspec
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bagport.staging import EPISODE_SUMMARY, read_staged_table, read_summary, write_json


def _frames_like() -> pa.Table:
    """A staged frame table's shapes: dotted names, list and fixed-size list columns, schema metadata."""
    table = pa.table(
        {
            "observation.state": pa.array([[0.5, -1.25], [2.0, 3.5]], pa.list_(pa.float32())),
            "action": pa.array([[1.0] * 3, [2.0] * 3], pa.list_(pa.float64(), 3)),
            "timestamp": pa.array([0.0, 1 / 30], pa.float32()),
            "task": ["pick", "pick"],
        }
    )
    return table.replace_schema_metadata({b"bagport": b"staged"})


@pytest.mark.parametrize("scheme", ["file", "memory"])
def test_a_staged_table_reads_back_whole(tmp_path: Path, scheme: str) -> None:
    table = _frames_like()
    uri = str(tmp_path / "frames.parquet") if scheme == "file" else "memory://staging/ep000/frames.parquet"
    with fsspec.open(uri, "wb") as handle:
        pq.write_table(table, handle)
    read = read_staged_table(uri)
    assert read.equals(table)
    assert read.schema.metadata == table.schema.metadata


def test_a_summary_cut_short_is_an_episode_that_never_completed(tmp_path: Path) -> None:
    """A summary left half written (a run killed while an older bagport wrote it) is read as no summary:
    the episode is converted again, as the plan decides, not failed on."""
    folder = tmp_path / "episodes" / "ep000"
    folder.mkdir(parents=True)
    (folder / EPISODE_SUMMARY).write_text('{"episode_id": "ep000", "bag_uri": "/bags/ep')
    assert read_summary(str(folder)) is None
    (folder / EPISODE_SUMMARY).write_text('{"episode_id": "ep000"}')  # whole, but not a summary
    assert read_summary(str(folder)) is None


def test_a_json_write_killed_before_it_ends_leaves_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "episodes" / "ep000" / EPISODE_SUMMARY
    write_json(str(target), {"episode_id": "ep000", "frames": 3})
    assert json.loads(target.read_text()) == {"episode_id": "ep000", "frames": 3}
    assert [p.name for p in target.parent.iterdir()] == [EPISODE_SUMMARY]  # nothing beside it

    def killed(self: Path, target: str) -> None:
        raise KeyboardInterrupt  # the process stops between writing and renaming

    fresh = tmp_path / "episodes" / "ep001" / EPISODE_SUMMARY
    monkeypatch.setattr(Path, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        write_json(str(fresh), {"episode_id": "ep001", "frames": 3})
    assert not fresh.exists()  # no completion marker: the episode is converted again
    assert list(fresh.parent.iterdir()) == []  # nor its temporary file
    with pytest.raises(KeyboardInterrupt):
        write_json(str(target), {"episode_id": "ep000", "frames": 4})
    assert json.loads(target.read_text()) == {"episode_id": "ep000", "frames": 3}  # the earlier one, whole
    assert [p.name for p in target.parent.iterdir()] == [EPISODE_SUMMARY]


def test_two_writers_of_one_json_path_do_not_share_a_temporary_file(tmp_path: Path) -> None:
    """Threads of one process writing the same path (the thread runner) each write a whole file."""
    target = tmp_path / "segments.json"
    texts = [{"writer": i, "pad": "x" * 200_000} for i in range(8)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        list(pool.map(lambda data: write_json(str(target), data), texts))
    assert json.loads(target.read_text()) in texts
    assert [p.name for p in tmp_path.iterdir()] == ["segments.json"]


def test_a_json_file_gets_the_permissions_of_any_file_this_process_writes(tmp_path: Path) -> None:
    """Written through a temporary file, but readable as a plainly written one is (another user's process
    on the host may read a local staging store)."""
    plain = tmp_path / "plain.json"
    plain.write_text("{}")
    staged = tmp_path / "episode.json"
    write_json(str(staged), {})
    assert staged.stat().st_mode == plain.stat().st_mode
