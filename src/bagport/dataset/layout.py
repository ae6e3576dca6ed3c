"""Every path of the LeRobot v3.0 layout, defined once."""

from __future__ import annotations

__all__ = [
    "APPEND_RUN_RECORD_PATH",
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


def next_chunk_file(chunk_index: int, file_index: int, chunks_size: int) -> tuple[int, int]:
    """The (chunk, file) after this one: ``chunks_size`` files per chunk folder."""
    if file_index + 1 >= chunks_size:
        return chunk_index + 1, 0
    return chunk_index, file_index + 1
