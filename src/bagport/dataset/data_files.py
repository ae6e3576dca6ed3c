"""Write ``data/chunk-*/file-*.parquet``: many episodes per file, one row group each.

:func:`plan_data_files` decides which episodes go into which file before any is written, from each
episode's row-group bytes (:func:`bagport.data_table.episode_data_bytes`, measured by the worker that staged it); then
each file is written on its own (:func:`write_data_file`), in any process and any order."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from bagport.data_table import PARQUET_MAGIC_BYTES, DataTableWriter, episode_table
from bagport.dataset.layout import rotate_files
from bagport.staging import StagedFeature

__all__ = [
    "DataPlacement",
    "DataWritten",
    "plan_data_files",
    "task_counts",
    "write_data_file",
]

_MB = 1024 * 1024


@dataclass(frozen=True, slots=True)
class DataPlacement:
    chunk_index: int
    file_index: int
    from_index: int
    to_index: int


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
    writer: DataTableWriter | None = None
    try:
        for episode_index, frames_uri in enumerate(frames_uris, start=first_episode_index):
            table = episode_table(frames_uri, episode_index, first_index, task_index, vectors)
            if writer is None:
                writer = DataTableWriter(str(path), table, vectors)
            writer.add(table)
            placements.append(DataPlacement(*chunk_file, first_index, first_index + table.num_rows))
            counts.append(task_counts(table))
            first_index += table.num_rows
    finally:
        if writer is not None:
            writer.close()
    return DataWritten(tuple(placements), tuple(counts))
