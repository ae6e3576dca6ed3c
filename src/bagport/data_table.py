"""A staged episode's frame table as a LeRobot data file holds it (one row group per episode, snappy, with
LeRobot's ``huggingface`` schema metadata), and the bytes that row group takes: shared by the worker that
stages an episode (it measures its row group for the plan) and the writer of the data files
(:mod:`bagport.dataset.data_files`)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from bagport.staging import StagedFeature, read_staged_table

__all__ = [
    "PARQUET_MAGIC_BYTES",
    "DataTableWriter",
    "episode_data_bytes",
    "episode_table",
    "hf_features_metadata",
]

PARQUET_MAGIC_BYTES = 4
"""``PAR1``: what a parquet file holds before its first row group."""


def _is_scalar(feature: StagedFeature) -> bool:
    """LeRobot stores shape ``(1,)`` features as plain values, not one-element lists."""
    return tuple(feature.shape) == (1,)


def hf_features_metadata(vectors: Sequence[StagedFeature]) -> bytes:
    """The ``huggingface`` schema metadata LeRobot's own writer puts in data parquet files."""
    features: dict[str, object] = {
        f.key: {"dtype": f.dtype, "_type": "Value"}
        if _is_scalar(f)
        else {"feature": {"dtype": f.dtype, "_type": "Value"}, "length": f.shape[0], "_type": "List"}
        for f in vectors
    }
    features["timestamp"] = {"dtype": "float32", "_type": "Value"}
    for name in ("frame_index", "episode_index", "index", "task_index"):
        features[name] = {"dtype": "int64", "_type": "Value"}
    return json.dumps({"info": {"features": features}}).encode()


def episode_table(
    frames: str | pa.Table,
    episode_index: int,
    first_index: int,
    task_index: Mapping[str, int] | None,
    vectors: Sequence[StagedFeature],
) -> pa.Table:
    """The episode's rows as a data file holds them, from its staged frame table (by URI, or the table in
    hand); ``task_index``: ``None`` numbers the episode's own tasks in the order they first appear."""
    staged = frames if isinstance(frames, pa.Table) else read_staged_table(frames)
    rows = staged.num_rows
    tasks = [str(t) for t in staged.column("task").to_pylist()]
    numbers = task_index if task_index is not None else {t: i for i, t in enumerate(dict.fromkeys(tasks))}
    columns: dict[str, Any] = {
        f.key: pc.list_flatten(staged.column(f.key)) if _is_scalar(f) else staged.column(f.key)
        for f in vectors
    }
    columns["timestamp"] = staged.column("timestamp")
    columns["frame_index"] = staged.column("frame_index")
    columns["episode_index"] = pa.array(np.full(rows, episode_index, dtype=np.int64))
    columns["index"] = pa.array(np.arange(first_index, first_index + rows, dtype=np.int64))
    columns["task_index"] = pa.array(np.array([numbers[t] for t in tasks], dtype=np.int64))
    return pa.table(columns)


class DataTableWriter:
    """A data file's parquet writer: the first episode's schema (with LeRobot's metadata), snappy, one
    row group per episode as LeRobot's writer puts them."""

    def __init__(self, where: str | pa.NativeFile, first: pa.Table, vectors: Sequence[StagedFeature]) -> None:
        self.schema = first.schema.with_metadata({b"huggingface": hf_features_metadata(vectors)})
        self.parquet = pq.ParquetWriter(where, self.schema, compression="snappy")

    def add(self, table: pa.Table) -> None:
        self.parquet.write_table(table.cast(self.schema), row_group_size=max(1, table.num_rows))

    def close(self) -> None:
        self.parquet.close()


def episode_data_bytes(frames: str | pa.Table, vectors: Sequence[StagedFeature]) -> int:
    """The bytes the episode's row group adds to a data file (what LeRobot's rotation rule counts),
    encoded as :func:`bagport.dataset.data_files.write_data_file` encodes it but with episode and global
    indices from 0: the final ``index`` values change the snappy-compressed size by a few bytes (the plan's
    estimate, docs/fleet.md). ``frames``: the staged frame table, by URI or in hand."""
    table = episode_table(frames, 0, 0, None, vectors)
    sink = pa.BufferOutputStream()
    writer = DataTableWriter(sink, table, vectors)
    try:
        writer.add(table)
        return int(sink.tell()) - PARQUET_MAGIC_BYTES  # the row group; the footer comes at close
    finally:
        writer.close()
