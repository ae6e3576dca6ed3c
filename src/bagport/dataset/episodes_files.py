"""Write ``meta/episodes/chunk-*/file-*.parquet``: the episodes' rows in row groups that start at LeRobot's
buffer size and double, in files rotated by size as LeRobot's writer rotates them."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from bagport.dataset.layout import EPISODES_PATH, next_chunk_file

__all__ = ["EPISODES_BATCH", "EPISODES_GROUP_MAX", "write_episode_files"]

EPISODES_BATCH = 10
"""The first ``meta/episodes`` row group's rows (LeRobot buffers as many before writing); see
:data:`EPISODES_GROUP_MAX`."""


EPISODES_GROUP_MAX = 1000
"""The largest ``meta/episodes`` row group (rows): row groups start at :data:`EPISODES_BATCH`
rows and double up to this. A parquet writer keeps every row group's metadata until it closes (with
~100 stats columns, ~100 KB a row group with the footer it builds at close), so ten rows a row group would
grow the commit's memory with the number of episodes (~40 MB at 2,000); doubling keeps it to a few
row groups (LeRobot reads any)."""


def _episode_groups(tables: Iterable[pa.Table]) -> Iterator[pa.Table]:
    """The rows of ``tables`` regrouped: :data:`EPISODES_BATCH` rows, then each group twice the one before,
    up to :data:`EPISODES_GROUP_MAX` (the last: what is left)."""
    pending: list[pa.Table] = []
    rows, want = 0, EPISODES_BATCH
    for table in tables:
        offset = 0
        while offset < table.num_rows:
            take = min(want - rows, table.num_rows - offset)
            pending.append(table.slice(offset, take))
            rows, offset = rows + take, offset + take
            if rows == want:
                yield pa.concat_tables(pending)
                pending, rows, want = [], 0, min(2 * want, EPISODES_GROUP_MAX)
    if rows:
        yield pa.concat_tables(pending)


def write_episode_files(
    root: Path,
    tables: Iterable[pa.Table],
    *,
    start: tuple[int, int],
    file_size_in_mb: float,
    chunks_size: int,
) -> list[tuple[int, int]]:
    """Write the episode rows (``tables``, in order, of one schema) from file ``start`` on, rotating by size
    as LeRobot's writer does: a new file starts when the current one's size on disk plus the next row
    group's estimated size (the file's average bytes per row so far) would reach ``file_size_in_mb``
    (LeRobot uses ``data_files_size_in_mb`` for its episodes files too). The first row group holds
    :data:`EPISODES_BATCH` rows (LeRobot's buffer), each next one twice as many, up to
    :data:`EPISODES_GROUP_MAX` (:func:`_episode_groups`). Returns the files written."""
    limit_bytes = file_size_in_mb * 1024 * 1024
    chunk_file = start
    written = [chunk_file]
    rows_in_file = 0
    writer: pq.ParquetWriter | None = None
    path = root / EPISODES_PATH.format(chunk_index=chunk_file[0], file_index=chunk_file[1])
    columns = {"meta/episodes/chunk_index": pa.int64(), "meta/episodes/file_index": pa.int64()}

    try:
        for group in _episode_groups(tables):
            batch = group
            if writer is not None and rows_in_file:
                size = path.stat().st_size
                if size + size / rows_in_file * batch.num_rows >= limit_bytes:
                    writer.close()
                    writer, rows_in_file = None, 0
                    chunk_file = next_chunk_file(*chunk_file, chunks_size)
                    written.append(chunk_file)
            first = batch.num_columns
            for n, (name, kind) in enumerate(columns.items()):
                batch = batch.add_column(first + n, name, pa.array([chunk_file[n]] * batch.num_rows, kind))
            if writer is None:
                path = root / EPISODES_PATH.format(chunk_index=chunk_file[0], file_index=chunk_file[1])
                path.parent.mkdir(parents=True, exist_ok=True)
                writer = pq.ParquetWriter(path, batch.schema)
            writer.write_table(batch, row_group_size=batch.num_rows)
            rows_in_file += batch.num_rows
    finally:
        if writer is not None:
            writer.close()
    return written
