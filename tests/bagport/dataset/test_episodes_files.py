"""``meta/episodes`` row groups: ten rows first (LeRobot's buffer), then each twice the one before up to
:data:`EPISODES_GROUP_MAX`, so a writer that keeps every row group's metadata until it closes stays small;
the rows, their order and the file they name are unchanged."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from bagport.dataset.episodes_files import EPISODES_BATCH, EPISODES_GROUP_MAX, write_episode_files


def _tables(rows: int, per_table: int) -> list[pa.Table]:
    return [
        pa.table({"episode_index": pa.array(range(start, min(start + per_table, rows)), pa.int64())})
        for start in range(0, rows, per_table)
    ]


def test_row_groups_double_from_lerobots_ten_rows(tmp_path: Path) -> None:
    written = write_episode_files(
        tmp_path, _tables(2500, 100), start=(0, 0), file_size_in_mb=100, chunks_size=1000
    )
    assert written == [(0, 0)]
    path = tmp_path / "meta/episodes/chunk-000/file-000.parquet"
    meta = pq.read_metadata(path)
    sizes = [meta.row_group(n).num_rows for n in range(meta.num_row_groups)]
    assert (EPISODES_BATCH, EPISODES_GROUP_MAX) == (10, 1000)
    assert sizes == [10, 20, 40, 80, 160, 320, 640, 1000, 230]
    table = pq.read_table(path)
    assert table.column("episode_index").to_pylist() == list(range(2500))
    assert set(table.column("meta/episodes/file_index").to_pylist()) == {0}


def test_a_new_file_starts_by_size_before_a_row_group(tmp_path: Path) -> None:
    """With a limit below one row group's size every row group after the first starts a new file, and the
    rows of each file name it (chunks of 2 files)."""
    written = write_episode_files(tmp_path, _tables(75, 7), start=(0, 1), file_size_in_mb=1e-4, chunks_size=2)
    assert written == [(0, 1), (1, 0), (1, 1), (2, 0)]  # 10, 20, 40, then the 5 left
    for (chunk, file), rows in zip(written, [10, 20, 40, 5], strict=True):
        table = pq.read_table(tmp_path / f"meta/episodes/chunk-{chunk:03d}/file-{file:03d}.parquet")
        assert table.num_rows == rows
        assert set(table.column("meta/episodes/chunk_index").to_pylist()) == {chunk}
        assert set(table.column("meta/episodes/file_index").to_pylist()) == {file}
