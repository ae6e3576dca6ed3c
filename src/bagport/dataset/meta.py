"""``meta/``: info.json, tasks.parquet, episodes parquet and stats.json."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.columns import column_matrix
from bagport.dataset.base import DatasetBase
from bagport.dataset.data_files import DataPlacement
from bagport.dataset.layout import (
    CODEBASE_VERSION,
    DATA_PATH,
    DEFAULT_FEATURES,
    EPISODES_PATH,
    HISTOGRAMS_PATH,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_PATH,
)
from bagport.dataset.videos import VideoPlacement
from bagport.staging import STATS_FILE, EpisodeSummary, StagedFeature
from bagport.stats import (
    FeatureStats,
    QuantileHistogram,
    merge_feature_stats,
    merge_histograms,
    stats_from_json,
    vector_stats,
)
from bagport.video.depth import histogram_levels

__all__ = [
    "DatasetLimits",
    "EpisodeStats",
    "build_info",
    "dataset_quantiles",
    "load_episode_stats",
    "write_meta",
]


@dataclass(frozen=True, slots=True)
class DatasetLimits:
    chunks_size: int = 1000
    data_files_size_in_mb: float = 100
    video_files_size_in_mb: float = 200

    @classmethod
    def from_info(cls, info: dict[str, Any]) -> DatasetLimits:
        """The limits an existing dataset was written with (an append keeps them)."""
        return cls(
            chunks_size=int(info["chunks_size"]),
            data_files_size_in_mb=float(info["data_files_size_in_mb"]),
            video_files_size_in_mb=float(info["video_files_size_in_mb"]),
        )


@dataclass(frozen=True, slots=True)
class EpisodeStats:
    stats: dict[str, FeatureStats]
    histograms: dict[str, npt.NDArray[np.int64]]


def load_episode_stats(
    summary: EpisodeSummary, episode_index: int, placement: DataPlacement, task_indices: npt.NDArray[np.int64]
) -> EpisodeStats:
    fs, path = url_to_fs(summary.file(STATS_FILE))
    with fs.open(path, "r") as handle:
        raw: dict[str, dict[str, Any]] = json.load(handle)
    stats: dict[str, FeatureStats] = {}
    histograms: dict[str, npt.NDArray[np.int64]] = {}
    for key, values in raw.items():
        hist = values.pop("histogram", None)
        if hist is not None:
            histograms[key] = np.asarray(hist, dtype=np.int64)
        stats[key] = stats_from_json(values)
    frames = summary.frames
    frame_index = np.arange(frames, dtype=np.int64)
    stats["timestamp"] = vector_stats((frame_index / summary.fps).astype(np.float32))
    stats["frame_index"] = vector_stats(frame_index)
    stats["episode_index"] = vector_stats(np.full(frames, episode_index))
    stats["index"] = vector_stats(np.arange(placement.from_index, placement.to_index))
    stats["task_index"] = vector_stats(task_indices)
    return EpisodeStats(stats, histograms)


def build_info(
    features: Sequence[StagedFeature],
    *,
    robot_type: str,
    fps: int,
    total_episodes: int,
    total_frames: int,
    total_tasks: int,
    limits: DatasetLimits,
) -> dict[str, Any]:
    feature_dict: dict[str, Any] = {}
    for f in features:
        entry: dict[str, Any] = {
            "dtype": f.dtype,
            "shape": list(f.shape),
            "names": list(f.names) if f.names else None,
        }
        if f.video_info is not None:
            entry["info"] = f.video_info
        feature_dict[f.key] = entry
    feature_dict.update({k: dict(v) for k, v in DEFAULT_FEATURES.items()})
    has_video = any(f.video_info is not None for f in features)
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "fps": fps,
        "features": feature_dict,
        "total_episodes": total_episodes,
        "total_frames": total_frames,
        "total_tasks": total_tasks,
        "chunks_size": limits.chunks_size,
        "data_files_size_in_mb": limits.data_files_size_in_mb,
        "video_files_size_in_mb": limits.video_files_size_in_mb,
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if has_video else None,
        "splits": {"train": f"0:{total_episodes}"},
    }


def _stat_columns(stats: dict[str, FeatureStats], keys: Sequence[str]) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for key in keys:
        for stat, value in stats[key].items():
            row[f"stats/{key}/{stat}"] = np.asarray(value).tolist()
    return row


_LABEL_COLUMNS = ("label", "label_note")


def _has_label_columns(root: Path) -> bool:
    """Whether the dataset's existing episode files carry the label columns (older ones do not)."""
    existing = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    return not existing or all(name in pq.read_schema(existing[0]).names for name in _LABEL_COLUMNS)


def dataset_quantiles(
    data_files: Sequence[str | Path], merged: dict[str, FeatureStats]
) -> dict[str, dict[str, npt.NDArray[np.float64]]]:
    """Quantiles of each vector feature over every frame of ``data_files`` (one streaming pass), between
    the merged min and max; shaped like the merged stats."""
    if not merged or not data_files:
        return {}
    counters = {key: QuantileHistogram(stats["min"], stats["max"]) for key, stats in merged.items()}
    for uri in data_files:
        fs, path = url_to_fs(str(uri))
        with fs.open(path, "rb") as handle:
            for batch in pq.ParquetFile(handle).iter_batches(batch_size=65_536, columns=list(counters)):
                for key, counter in counters.items():
                    counter.update(column_matrix(batch.column(key)))
    return {
        key: {q: value.reshape(np.shape(merged[key]["min"])) for q, value in counter.quantiles().items()}
        for key, counter in counters.items()
    }


def write_meta(
    root: Path,
    summaries: Sequence[EpisodeSummary],
    features: Sequence[StagedFeature],
    tasks: Sequence[str],
    data: Sequence[DataPlacement],
    videos: dict[str, list[VideoPlacement]],
    episode_stats: Sequence[EpisodeStats],
    info: dict[str, Any],
    base: DatasetBase | None = None,
    data_files: Sequence[str | Path] = (),
) -> None:
    """Write ``meta/``; with ``base`` (an append) the new episodes continue the existing ones in a new
    episodes file, and stats merge with the existing dataset's. ``data_files`` are every data file
    of the dataset (the base's and the new ones): vector quantiles are computed over all their frames."""
    first_episode = base.episodes if base is not None else 0
    episodes_file = base.next_episodes if base is not None else (0, 0)
    (root / "meta").mkdir(parents=True, exist_ok=True)
    (root / INFO_PATH).write_text(json.dumps(info, indent=4))
    task_frame = pd.DataFrame(
        {"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, name="task")
    )
    task_frame.to_parquet(root / TASKS_PATH)

    stat_keys = [f.key for f in features] + list(DEFAULT_FEATURES)
    rows = []
    for n, (summary, placement, ep_stats) in enumerate(zip(summaries, data, episode_stats, strict=True)):
        episode_index = first_episode + n
        row: dict[str, Any] = {
            "episode_index": episode_index,
            "tasks": list(summary.tasks),
            "length": summary.frames,
            "data/chunk_index": placement.chunk_index,
            "data/file_index": placement.file_index,
            "dataset_from_index": placement.from_index,
            "dataset_to_index": placement.to_index,
            "label": summary.label,
            "label_note": summary.note,
        }
        for key, placed in videos.items():
            video = placed[n]
            row[f"videos/{key}/chunk_index"] = video.chunk_index
            row[f"videos/{key}/file_index"] = video.file_index
            row[f"videos/{key}/from_timestamp"] = video.from_timestamp_s
            row[f"videos/{key}/to_timestamp"] = video.to_timestamp_s
        row.update(_stat_columns(ep_stats.stats, stat_keys))
        row["meta/episodes/chunk_index"] = episodes_file[0]
        row["meta/episodes/file_index"] = episodes_file[1]
        rows.append(row)
    episodes_path = root / EPISODES_PATH.format(chunk_index=episodes_file[0], file_index=episodes_file[1])
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pylist(rows)
    for name in _LABEL_COLUMNS:  # typed even when every episode's label is null
        table = table.set_column(
            table.schema.get_field_index(name), name, table.column(name).cast(pa.string())
        )
    if base is not None and not _has_label_columns(root):
        table = table.drop_columns(list(_LABEL_COLUMNS))  # LeRobot loads episode files of one schema only
    pq.write_table(table, episodes_path)

    merged_stats: dict[str, FeatureStats] = {}
    quantiles: list[str] = []
    histograms: dict[str, list[int]] = {}
    levels = {f.key: histogram_levels(f.video_info) for f in features if f.video_info is not None}
    for key in stat_keys:
        parts = [ep.stats[key] for ep in episode_stats]
        if base is not None:
            parts.append(base.stats[key])
        if all(key in ep.histograms for ep in episode_stats) and (base is None or key in base.histograms):
            hists = [ep.histograms[key] for ep in episode_stats]
            if base is not None:
                hists.append(base.histograms[key])
            value = merge_histograms(hists, [int(p["count"][0]) for p in parts], levels.get(key))
            histograms[key] = np.sum(np.stack(hists), axis=0).tolist()
        else:
            value = merge_feature_stats(parts)
            quantiles.append(key)
        merged_stats[key] = value
    # vector quantiles over every frame (base and new files), within one bin: see bagport.stats.quantiles
    for key, values in dataset_quantiles(data_files, {k: merged_stats[k] for k in quantiles}).items():
        merged_stats[key].update(values)
    merged = {
        key: {stat: np.asarray(v).tolist() for stat, v in value.items()}
        for key, value in merged_stats.items()
    }
    (root / STATS_PATH).write_text(json.dumps(merged, indent=4))
    (root / HISTOGRAMS_PATH).parent.mkdir(parents=True, exist_ok=True)
    (root / HISTOGRAMS_PATH).write_text(json.dumps(histograms))
