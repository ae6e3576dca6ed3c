"""Every path of the LeRobot v3.0 layout, defined once."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

__all__ = [
    "APPEND_RUN_RECORD_PATH",
    "BAGS_INDEX_PATH",
    "CODEBASE_VERSION",
    "DATA_PATH",
    "DEFAULT_FEATURES",
    "EPISODES_PATH",
    "HISTOGRAMS_PATH",
    "INFO_PATH",
    "JOURNAL_PATH",
    "PROVENANCE_PATH",
    "RUN_RECORD_PATH",
    "STAGED_DIR",
    "SKETCHES_PATH",
    "STATS_PATH",
    "TASKS_PATH",
    "VIDEO_PATH",
    "next_chunk_file",
    "run_number",
    "rotate_files",
]

CODEBASE_VERSION = "v3.0"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
# bagport's own metadata lives beside, never inside, info.json (LeRobot rewrites info.json).
PROVENANCE_PATH = "meta/provenance/" + CHUNK_FILE + ".parquet"
RUN_RECORD_PATH = "meta/provenance/run.json"
APPEND_RUN_RECORD_PATH = "meta/provenance/run-{run:03d}.json"
BAGS_INDEX_PATH = "meta/provenance/bags.parquet"
"""Every run's bags in one table (bagport.dataset.bags_index): an append reads it, not every run record."""
JOURNAL_PATH = ".bagport-journal.json"
"""While a publish or append commits: its intent record (see bagport.dataset.journal)."""
STAGED_DIR = ".bagport-staged-{run_id}"
"""On an object store, where a publish uploads its files before the commit (inside the dataset root)."""
HISTOGRAMS_PATH = "meta/provenance/image_histograms.json"
"""Dataset-wide pixel histograms per camera, so an append merges image stats exactly."""
SKETCHES_PATH = "meta/provenance/quantile_sketches.json"
"""Merged KLL sketches per vector feature dimension, so an append merges quantiles without old data."""

DEFAULT_FEATURES: dict[str, dict[str, object]] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}


_RUN_RECORD_NAME = re.compile(r"run(?:-(\d+))?\.json")


def run_number(record_path: str) -> int | None:
    """The run a run record's path names (``run.json``: 0, ``run-007.json``: 7), else ``None``."""
    match = _RUN_RECORD_NAME.fullmatch(record_path.rsplit("/", 1)[-1])
    return int(match.group(1) or 0) if match else None


def next_chunk_file(chunk_index: int, file_index: int, chunks_size: int) -> tuple[int, int]:
    """The (chunk, file) after this one: ``chunks_size`` files per chunk folder."""
    if file_index + 1 >= chunks_size:
        return chunk_index + 1, 0
    return chunk_index, file_index + 1


def rotate_files(
    sizes_bytes: Sequence[int],
    frames: Sequence[int],
    reaches: Callable[[int, int, int], bool],
    *,
    chunks_size: int,
    start: tuple[int, int] = (0, 0),
) -> list[tuple[tuple[int, int], list[int]]]:
    """Group episodes (by their sizes and frame counts, in order) into files: ((chunk, file), positions)
    each, at least one episode a file (an episode never splits). A file rotates when ``reaches(its bytes
    so far, its frames so far, the next position)``, the caller's size rule; ``start``: where the first
    file goes (after the last one, for an append)."""
    groups: list[tuple[tuple[int, int], list[int]]] = []
    where = start
    group: list[int] = []
    group_bytes = group_frames = 0
    for n, (size, count) in enumerate(zip(sizes_bytes, frames, strict=True)):
        if group and reaches(group_bytes, group_frames, n):
            groups.append((where, group))
            where = next_chunk_file(*where, chunks_size)
            group, group_bytes, group_frames = [], 0, 0
        group.append(n)
        group_bytes += size
        group_frames += count
    if group:
        groups.append((where, group))
    return groups
