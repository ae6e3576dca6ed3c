"""An existing dataset as the base of an append: what is there, and where new files go.

Appending never rewrites existing data or video files: new episodes go to the files after
the last existing ones, and only ``meta/`` is replaced (see :mod:`bagport.dataset.write`).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd
import pyarrow.parquet as pq
from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.dataset.checksums import latest_record
from bagport.dataset.layout import HISTOGRAMS_PATH, INFO_PATH, STATS_PATH, TASKS_PATH, next_chunk_file
from bagport.dataset.sketches import DatasetSketches, read_sketches
from bagport.errors import DatasetWriteError
from bagport.stats import FeatureStats, stats_from_json

__all__ = ["DatasetBase", "read_base", "read_info", "record_head", "record_string", "record_tail"]

_CHUNK_FILE = re.compile(r"chunk-(\d+)/file-(\d+)\.\w+$")


@dataclass(frozen=True, slots=True)
class DatasetBase:
    info: dict[str, Any]
    tasks: list[str]
    stats: dict[str, FeatureStats]
    histograms: dict[str, npt.NDArray[np.int64]]
    next_data: tuple[int, int]
    next_video: dict[str, tuple[int, int]]
    next_episodes: tuple[int, int]
    next_provenance: tuple[int, int]
    run_number: int
    """Runs recorded so far (``meta/provenance/run.json`` is run 0, appends add ``run-001.json``...)."""
    data_files: tuple[str, ...] = ()
    """The existing data files (never rewritten; read only to sketch a dataset that has no sketches yet)."""
    checksums: dict[str, str] | None = None
    """SHA-256 of every existing file, from the newest run record plus that record's own (``None``: not
    recorded); an append carries them over instead of reading the files again."""
    sketches: DatasetSketches | None = None
    """The dataset's merged quantile sketches (``None``: written before they were kept)."""
    root: str = ""
    """Where the dataset is (a path or fsspec URI): an append reads its few old ``meta/`` files from here."""
    label_columns: bool = True
    """Whether its episodes files have the label columns (older ones do not; one schema for LeRobot)."""

    @property
    def episodes(self) -> int:
        return int(self.info["total_episodes"])

    @property
    def frames(self) -> int:
        return int(self.info["total_frames"])


def _next(fs: AbstractFileSystem, folder: str, pattern: str, chunks_size: int) -> tuple[int, int]:
    found = []
    for path in fs.glob(f"{folder}/{pattern}"):
        match = _CHUNK_FILE.search(str(path))
        if match:
            found.append((int(match.group(1)), int(match.group(2))))
    if not found:
        return 0, 0
    return next_chunk_file(*max(found), chunks_size)


def _read_json(fs: AbstractFileSystem, path: str) -> Any:
    with fs.open(path, "r", encoding="utf-8") as handle:
        return json.load(handle)


_TOP_FILES = b'\n  "files": '
"""Where the ``files`` digests start in a run record (written as ``json.dumps(indent=2)`` writes it: a
top-level key is the only text at two spaces' indent, strings hold no raw newline)."""


_TOP_EPISODES = b'\n  "episodes": '


def record_head(raw: bytes) -> dict[str, Any]:
    """A run record's entries before its episodes (the contract, the manifest, the exclusions and failures):
    parsed without the episodes' entries, which follow; any other layout is parsed whole."""
    at = raw.find(_TOP_EPISODES)
    if at >= 0:
        try:
            head: dict[str, Any] = json.loads(raw[:at].rstrip().rstrip(b",") + b"\n}")
            return head
        except json.JSONDecodeError:
            pass
    whole: dict[str, Any] = json.loads(raw)
    return whole


def record_tail(raw: bytes) -> dict[str, Any]:
    """A run record's ``files`` (the digests, after its episodes) and ``files_complete``: only its tail is
    parsed, so reading the record of a large run does not parse every episode's entry; any other layout
    is parsed whole."""
    at = raw.rfind(_TOP_FILES)
    if at >= 0:
        try:
            tail: dict[str, Any] = json.loads(b"{" + raw[at + 1 :])
            return tail
        except json.JSONDecodeError:
            pass
    whole: dict[str, Any] = json.loads(raw)
    return {key: whole[key] for key in ("files", "files_complete") if key in whole}


def record_string(raw: bytes, key: str) -> str | None:
    """A top-level string ``key`` of a run record, read from its own line (no parse of the rest);
    ``None`` when the record has no such string."""
    marker = b'\n  "' + key.encode() + b'": '
    at = raw.find(marker)
    if at < 0:
        return None
    line = raw[at + len(marker) : raw.find(b"\n", at + len(marker))].rstrip(b",")
    try:
        value = json.loads(line)
    except json.JSONDecodeError:
        return None
    return value if isinstance(value, str) else None


def read_info(root: str | Path) -> dict[str, Any]:
    """The ``meta/info.json`` of the dataset at ``root`` (a local path or fsspec URI) alone: what an append's
    plan and the commit's re-check need, without the rest :func:`read_base` reads (stats, sketches, tasks,
    the newest run record). A folder without one is not a LeRobot dataset: refused."""
    fs, path = url_to_fs(str(root))
    try:
        info: dict[str, Any] = _read_json(fs, f"{path.rstrip('/')}/{INFO_PATH}")
    except FileNotFoundError:
        raise DatasetWriteError(
            f"{root} is not a LeRobot dataset (no {INFO_PATH}); nothing was written. Fix: point --output at the "
            "dataset to append to, or write a new dataset to a new --output (without --append)."
        ) from None
    return info


def read_base(root: str | Path) -> DatasetBase:
    """Read what an append needs from the dataset at ``root`` (a local path or fsspec URI)."""
    info = read_info(root)
    fs, path = url_to_fs(str(root))
    path = path.rstrip("/")
    raw_histograms = (
        _read_json(fs, f"{path}/{HISTOGRAMS_PATH}") if fs.isfile(f"{path}/{HISTOGRAMS_PATH}") else {}
    )
    histograms = {key: np.asarray(value, dtype=np.int64) for key, value in raw_histograms.items()}
    raw_stats = _read_json(fs, f"{path}/{STATS_PATH}")
    with fs.open(f"{path}/{TASKS_PATH}", "rb") as handle:
        tasks_frame = pd.read_parquet(handle)
    tasks = [str(t) for t in tasks_frame.sort_values("task_index").index]
    chunks = int(info["chunks_size"])
    video_keys = [k for k, f in info["features"].items() if f.get("dtype") == "video"]
    runs = fs.glob(f"{path}/meta/provenance/run*.json")
    newest = latest_record([str(r) for r in runs])
    files = None
    if newest is not None:
        with fs.open(newest, "rb") as handle:
            raw = handle.read()
        files = record_tail(raw).get("files")
        if files is not None:
            files = {**files, str(newest)[len(path) + 1 :]: hashlib.sha256(raw).hexdigest()}
    return DatasetBase(
        info=info,
        tasks=tasks,
        stats={key: stats_from_json(value) for key, value in raw_stats.items()},
        histograms=histograms,
        next_data=_next(fs, f"{path}/data", "chunk-*/file-*.parquet", chunks),
        next_video={
            key: _next(fs, f"{path}/videos/{key}", "chunk-*/file-*.mp4", chunks) for key in video_keys
        },
        next_episodes=_next(fs, f"{path}/meta/episodes", "chunk-*/file-*.parquet", chunks),
        next_provenance=_next(fs, f"{path}/meta/provenance", "chunk-*/file-*.parquet", chunks),
        run_number=len(runs),
        data_files=tuple(
            fs.unstrip_protocol(p) for p in sorted(fs.glob(f"{path}/data/chunk-*/file-*.parquet"))
        ),
        checksums=files,
        sketches=read_sketches(fs, path),
        root=fs.unstrip_protocol(path),
        label_columns=_has_label_columns(fs, path),
    )


def _has_label_columns(fs: AbstractFileSystem, path: str) -> bool:
    """Whether the dataset's episodes files carry the label columns (its first one's schema: a footer read)."""
    existing = sorted(fs.glob(f"{path}/meta/episodes/chunk-*/file-*.parquet"))
    if not existing:
        return True
    with fs.open(existing[0], "rb") as handle:
        names = pq.read_schema(handle).names
    return all(name in names for name in ("label", "label_note"))
