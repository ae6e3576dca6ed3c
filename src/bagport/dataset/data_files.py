"""Write ``data/chunk-*/file-*.parquet``: many episodes per file, one row group each.

:func:`plan_data_files` decides which episodes go into which file before any is written, from each
episode's row-group bytes (:func:`episode_data_bytes`, measured by the worker that staged it); then
each file is written on its own (:func:`write_data_file`), in any process and any order."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.layout import rotate_files
from bagport.staging import StagedFeature

__all__ = [
    "DataPlacement",
    "DataWritten",
    "episode_data_bytes",
    "hf_features_metadata",
    "plan_data_files",
    "task_counts",
    "write_data_file",
]

_MB = 1024 * 1024
PARQUET_MAGIC_BYTES = 4
"""``PAR1``: what a parquet file holds before its first row group."""


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
    task_index: Mapping[str, int] | None,
    vectors: Sequence[StagedFeature],
) -> pa.Table:
    """The episode's rows as a data file holds them (``task_index``: ``None`` numbers the episode's own
    tasks in the order they first appear)."""
    fs, path = url_to_fs(frames_uri)
    with fs.open(path, "rb") as handle:
        staged = pq.read_table(handle)
    frames = staged.num_rows
    tasks = [str(t) for t in staged.column("task").to_pylist()]
    numbers = task_index if task_index is not None else {t: i for i, t in enumerate(dict.fromkeys(tasks))}
    columns: dict[str, Any] = {
        f.key: pc.list_flatten(staged.column(f.key)) if _is_scalar(f) else staged.column(f.key)
        for f in vectors
    }
    columns["timestamp"] = staged.column("timestamp")
    columns["frame_index"] = staged.column("frame_index")
    columns["episode_index"] = pa.array(np.full(frames, episode_index, dtype=np.int64))
    columns["index"] = pa.array(np.arange(first_index, first_index + frames, dtype=np.int64))
    columns["task_index"] = pa.array(np.array([numbers[t] for t in tasks], dtype=np.int64))
    return pa.table(columns)


class _Writer:
    """A data file's parquet writer: the first episode's schema (with LeRobot's metadata), snappy, one
    row group per episode as LeRobot's writer puts them."""

    def __init__(self, where: str | pa.NativeFile, first: pa.Table, vectors: Sequence[StagedFeature]) -> None:
        self.schema = first.schema.with_metadata({b"huggingface": hf_features_metadata(vectors)})
        self.parquet = pq.ParquetWriter(where, self.schema, compression="snappy")

    def add(self, table: pa.Table) -> None:
        self.parquet.write_table(table.cast(self.schema), row_group_size=max(1, table.num_rows))


def episode_data_bytes(frames_uri: str, vectors: Sequence[StagedFeature]) -> int:
    """The bytes the episode's row group adds to a data file (what LeRobot's rotation rule counts),
    encoded as :func:`write_data_file` encodes it but with episode and global indices from 0: the final
    ``index`` values change the snappy-compressed size by a few bytes (the plan's estimate, docs/fleet.md)."""
    table = _episode_table(frames_uri, 0, 0, None, vectors)
    sink = pa.BufferOutputStream()
    writer = _Writer(sink, table, vectors)
    try:
        writer.add(table)
        return int(sink.tell()) - PARQUET_MAGIC_BYTES  # the row group; the footer comes at close
    finally:
        writer.parquet.close()


def plan_data_files(
    episode_bytes: Sequence[int],
    episode_frames: Sequence[int],
    *,
    file_size_in_mb: float,
    chunks_size: int,
    start: tuple[int, int] = (0, 0),
) -> list[tuple[tuple[int, int], list[int]]]:
    """Group episodes into data files, ((chunk, file), positions) each, by LeRobot's rotation rule
    (``dataset_writer.py``) on the planned sizes: a file rotates when its bytes on disk so far (the
    ``PAR1`` magic and its row groups; the footer comes at close) + the episode's frames at the file's
    average bytes per frame reaches ``file_size_in_mb``. A file holds at least one episode."""
    limit = file_size_in_mb * _MB

    def reaches(file_bytes: int, file_frames: int, n: int) -> bool:
        on_disk = PARQUET_MAGIC_BYTES + file_bytes
        per_frame = on_disk / file_frames if file_frames else 0.0
        return on_disk + per_frame * episode_frames[n] >= limit

    return rotate_files(episode_bytes, episode_frames, reaches, chunks_size=chunks_size, start=start)


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


def write_data_file(
    path: Path,
    frames_uris: Sequence[str],
    vectors: Sequence[StagedFeature],
    task_index: Mapping[str, int],
    *,
    chunk_file: tuple[int, int],
    first_episode_index: int,
    first_index: int,
) -> DataWritten:
    """Stream staged frame tables (one ``frames.parquet`` per episode, in order) into the data file at
    ``path``, one row group each; the episodes' indices and global ``index`` values start at the given
    ones (where the plan put the file: :func:`plan_data_files`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    placements: list[DataPlacement] = []
    counts: list[tuple[tuple[int, int], ...]] = []
    writer: _Writer | None = None
    try:
        for episode_index, frames_uri in enumerate(frames_uris, start=first_episode_index):
            table = _episode_table(frames_uri, episode_index, first_index, task_index, vectors)
            if writer is None:
                writer = _Writer(str(path), table, vectors)
            writer.add(table)
            placements.append(DataPlacement(*chunk_file, first_index, first_index + table.num_rows))
            counts.append(task_counts(table))
            first_index += table.num_rows
    finally:
        if writer is not None:
            writer.parquet.close()
    return DataWritten(tuple(placements), tuple(counts))
