"""Staged files read back as they were written."""

from __future__ import annotations

from pathlib import Path

import fsspec
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bagport.staging import read_staged_table


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
