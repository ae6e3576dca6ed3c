"""Write ``data/chunk-*/file-*.parquet``: many episodes per file, one row group each."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.layout import DATA_PATH, next_chunk_file
from bagport.staging import StagedFeature

__all__ = ["DataPlacement", "DataWritten", "hf_features_metadata", "task_counts", "write_data_files"]

_MB = 1024 * 1024


@dataclass(frozen=True, slots=True)
class DataPlacement:
    chunk_index: int
    file_index: int
    from_index: int
    to_index: int


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


def _episode_table(
    frames_uri: str,
    episode_index: int,
    first_index: int,
    task_index: dict[str, int],
    vectors: Sequence[StagedFeature],
) -> pa.Table:
    fs, path = url_to_fs(frames_uri)
    with fs.open(path, "rb") as handle:
        staged = pq.read_table(handle)
    frames = staged.num_rows
    tasks = [str(t) for t in staged.column("task").to_pylist()]
    columns: dict[str, Any] = {
        f.key: pc.list_flatten(staged.column(f.key)) if _is_scalar(f) else staged.column(f.key)
        for f in vectors
    }
    columns["timestamp"] = staged.column("timestamp")
    columns["frame_index"] = staged.column("frame_index")
    columns["episode_index"] = pa.array(np.full(frames, episode_index, dtype=np.int64))
    columns["index"] = pa.array(np.arange(first_index, first_index + frames, dtype=np.int64))
    columns["task_index"] = pa.array(np.array([task_index[t] for t in tasks], dtype=np.int64))
    return pa.table(columns)


def _would_exceed(path: Path, frames_in_file: int, frames: int, file_size_in_mb: float) -> bool:
    """LeRobot's rotation rule (``dataset_writer.py``): size on disk + frames x average frame size >= limit."""
    size_mb = path.stat().st_size / _MB  # row groups are on disk once written; the footer comes at close
    per_frame_mb = size_mb / frames_in_file if frames_in_file else 0.0
    return size_mb + per_frame_mb * frames >= file_size_in_mb


def task_counts(table: pa.Table) -> tuple[tuple[int, int], ...]:
    """An episode's frames per task index (what its ``task_index`` stats need, without its frames)."""
    indices, counts = np.unique(table.column("task_index").to_numpy(), return_counts=True)
    return tuple((int(i), int(c)) for i, c in zip(indices, counts, strict=True))


@dataclass(frozen=True, slots=True)
class DataWritten:
    placements: tuple[DataPlacement, ...]
    """One per episode."""
    task_counts: tuple[tuple[tuple[int, int], ...], ...]
    """One per episode: (task index, frames) pairs."""
    files: tuple[str, ...]
    """The files written, relative to the root."""


def write_data_files(
    root: Path,
    frames_uris: Sequence[str],
    vectors: Sequence[StagedFeature],
    task_index: dict[str, int],
    *,
    file_size_in_mb: float,
    chunks_size: int,
    start: tuple[int, int] = (0, 0),
    first_episode_index: int = 0,
    first_index: int = 0,
) -> DataWritten:
    """Stream staged frame tables (one ``frames.parquet`` per episode) into rotated data files.

    A file rotates as LeRobot's writer rotates it: when its size on disk plus the episode's frames at
    the file's average bytes per frame reaches ``file_size_in_mb``.  ``start`` (chunk, file) and the
    first episode/global indices let an append continue a dataset.
    """
    placements: list[DataPlacement] = []
    counts: list[tuple[tuple[int, int], ...]] = []
    files: list[str] = []
    chunk, file = start
    writer: pq.ParquetWriter | None = None
    schema: pa.Schema | None = None
    path = root
    frames_in_file = 0
    metadata = {b"huggingface": hf_features_metadata(vectors)}
    try:
        for episode_index, frames_uri in enumerate(frames_uris, start=first_episode_index):
            table = _episode_table(frames_uri, episode_index, first_index, task_index, vectors)
            if writer is not None and _would_exceed(path, frames_in_file, table.num_rows, file_size_in_mb):
                writer.close()
                writer = None
                chunk, file = next_chunk_file(chunk, file, chunks_size)
            if writer is None or schema is None:
                files.append(DATA_PATH.format(chunk_index=chunk, file_index=file))
                path = root / files[-1]
                path.parent.mkdir(parents=True, exist_ok=True)
                schema = table.schema.with_metadata(metadata)
                writer = pq.ParquetWriter(path, schema, compression="snappy")
                frames_in_file = 0
            writer.write_table(table.cast(schema), row_group_size=max(1, table.num_rows))
            frames_in_file += table.num_rows
            placements.append(DataPlacement(chunk, file, first_index, first_index + table.num_rows))
            counts.append(task_counts(table))
            first_index += table.num_rows
    finally:
        if writer is not None:
            writer.close()
    return DataWritten(tuple(placements), tuple(counts), tuple(files))
