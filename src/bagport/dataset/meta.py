"""``meta/``: info.json, tasks.parquet, episodes parquet and stats.json."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
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
from bagport.dataset.episodes_files import EPISODES_BATCH, write_episode_files
from bagport.dataset.layout import (
    CODEBASE_VERSION,
    DATA_PATH,
    DEFAULT_FEATURES,
    HISTOGRAMS_PATH,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_PATH,
)
from bagport.dataset.sketches import DatasetSketches, sketches_from_data_files
from bagport.dataset.stats_parts import StatsParts
from bagport.dataset.videos import VideoPlacement
from bagport.staging import FRAMES_FILE, STATS_FILE, EpisodeSummary, StagedFeature
from bagport.stats import (
    FeatureStats,
    VectorSketch,
    column_stats,
    episode_sketch_fields,
    histogram_stats,
    merge_stacked_stats,
    stats_from_json,
)
from bagport.video.depth import histogram_levels

__all__ = [
    "DatasetLimits",
    "EpisodeStats",
    "build_info",
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


_SKETCH_FIELDS = ("sketch", "step_sketch", "max_step", "max_step_frame")


@dataclass(frozen=True, slots=True)
class EpisodeStats:
    stats: dict[str, FeatureStats]
    histograms: dict[str, npt.NDArray[np.int64]]
    largest_steps: dict[str, tuple[list[float], list[int]]] = field(default_factory=dict)
    """Per staged vector feature: each dimension's largest frame-to-frame step and the frame it ends at."""


def _vector_fields(summary: EpisodeSummary, key: str, values: dict[str, Any]) -> dict[str, Any]:
    """The sketch fields of a staged vector feature; an episode staged before they were kept is
    sketched from its staged frames (never from the dataset)."""
    if all(name in values for name in _SKETCH_FIELDS):
        return {name: values.pop(name) for name in _SKETCH_FIELDS}
    fs, path = url_to_fs(summary.file(FRAMES_FILE))
    with fs.open(path, "rb") as handle:
        return episode_sketch_fields(column_matrix(pq.read_table(handle, columns=[key]).column(key)))


def load_episode_stats(
    summary: EpisodeSummary,
    episode_index: int,
    placement: DataPlacement,
    task_indices: npt.NDArray[np.int64],
    sketches: DatasetSketches,
) -> EpisodeStats:
    """The episode's stats; its quantile sketches (every non-video feature) and step sketches (the staged
    vector features) are merged into ``sketches``, so memory holds one merged sketch, not one per episode."""
    fs, path = url_to_fs(summary.file(STATS_FILE))
    with fs.open(path, "r") as handle:
        raw: dict[str, dict[str, Any]] = json.load(handle)
    stats: dict[str, FeatureStats] = {}
    histograms: dict[str, npt.NDArray[np.int64]] = {}
    mine = DatasetSketches()
    largest: dict[str, tuple[list[float], list[int]]] = {}
    videos = {f.key for f in summary.features if f.video_info is not None}
    for key, values in raw.items():
        hist = values.pop("histogram", None)
        if hist is not None:
            histograms[key] = np.asarray(hist, dtype=np.int64)
        if key not in videos:
            fields = _vector_fields(summary, key, values)
            mine.values[key] = VectorSketch.from_json(fields["sketch"])
            mine.steps[key] = VectorSketch.from_json(fields["step_sketch"])
            largest[key] = (list(fields["max_step"]), list(fields["max_step_frame"]))
        stats[key] = stats_from_json(values)
    frames = summary.frames
    frame_index = np.arange(frames, dtype=np.int64)
    defaults: dict[str, npt.NDArray[Any]] = {
        "timestamp": (frame_index / summary.fps).astype(np.float32),
        "frame_index": frame_index,
        "episode_index": np.full(frames, episode_index),
        "index": np.arange(placement.from_index, placement.to_index),
        "task_index": task_indices,
    }
    for (key, column), column_stat in zip(
        defaults.items(), column_stats(list(defaults.values())), strict=True
    ):
        stats[key] = column_stat
        mine.values[key] = VectorSketch.of(column)
    sketches.merge(mine)
    return EpisodeStats(stats, histograms, largest)


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


_TABLE_ROWS = 10 * EPISODES_BATCH
"""Episode rows built into one table at once (memory stays flat in the number of episodes)."""


def _episode_tables(
    summaries: Sequence[EpisodeSummary],
    data: Sequence[DataPlacement],
    videos: dict[str, list[VideoPlacement]],
    episode_stats: Iterator[EpisodeStats],
    stat_keys: Sequence[str],
    first_episode: int,
    base: DatasetBase | None,
) -> Iterator[pa.Table]:
    """The ``meta/episodes`` rows, :data:`_TABLE_ROWS` at a time, all of the first table's schema."""
    schema: pa.Schema | None = None
    for offset in range(0, len(summaries), _TABLE_ROWS):
        rows = []
        for n in range(offset, min(offset + _TABLE_ROWS, len(summaries))):
            summary, placement = summaries[n], data[n]
            row: dict[str, Any] = {
                "episode_index": first_episode + n,
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
            row.update(_stat_columns(next(episode_stats).stats, stat_keys))
            rows.append(row)
        table = pa.Table.from_pylist(rows)
        for name in _LABEL_COLUMNS:  # typed even when every episode's label is null
            table = table.set_column(
                table.schema.get_field_index(name), name, table.column(name).cast(pa.string())
            )
        if base is not None and not base.label_columns:
            table = table.drop_columns(list(_LABEL_COLUMNS))  # LeRobot loads episode files of one schema only
        schema = schema or table.schema
        yield table.cast(schema)


def write_meta(
    root: Path,
    summaries: Sequence[EpisodeSummary],
    features: Sequence[StagedFeature],
    tasks: Sequence[str],
    data: Sequence[DataPlacement],
    videos: dict[str, list[VideoPlacement]],
    episode_stats: Iterable[EpisodeStats],
    info: dict[str, Any],
    sketches: DatasetSketches,
    base: DatasetBase | None = None,
) -> DatasetSketches:
    """Write ``meta/``; with ``base`` (an append) the new episodes continue the existing ones in new
    episodes files, and stats merge with the existing dataset's (its stored sketches, never its data
    files). ``sketches``: the new episodes' merged sketches (:func:`load_episode_stats`). Returns the
    dataset's merged sketches (the fleet distribution the jump check judges by). ``episode_stats`` may
    be a stream: each episode's stats are written as its row and kept only as numbers for the merge."""
    parts = StatsParts()

    def kept(stream: Iterable[EpisodeStats]) -> Iterator[EpisodeStats]:
        for ep in stream:
            parts.add(ep.stats, ep.histograms)
            yield ep

    first_episode = base.episodes if base is not None else 0
    (root / "meta").mkdir(parents=True, exist_ok=True)
    (root / INFO_PATH).write_text(json.dumps(info, indent=4))
    task_frame = pd.DataFrame(
        {"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, name="task")
    )
    task_frame.to_parquet(root / TASKS_PATH)

    stat_keys = [f.key for f in features] + list(DEFAULT_FEATURES)
    tables = _episode_tables(summaries, data, videos, kept(episode_stats), stat_keys, first_episode, base)
    write_episode_files(
        root,
        tables,
        start=base.next_episodes if base is not None else (0, 0),
        file_size_in_mb=float(info["data_files_size_in_mb"]),
        chunks_size=int(info["chunks_size"]),
    )
    return _write_stats(root, features, stat_keys, parts, sketches, base)


def _base_sketches(base: DatasetBase, keys: Sequence[str]) -> DatasetSketches:
    if base.sketches is not None:
        return base.sketches
    return sketches_from_data_files(base.data_files, keys)  # once, for a dataset older than its sketches


def _write_stats(
    root: Path,
    features: Sequence[StagedFeature],
    stat_keys: Sequence[str],
    parts: StatsParts,
    sketches: DatasetSketches,
    base: DatasetBase | None,
) -> DatasetSketches:
    """``stats.json`` (LeRobot's format), the pixel histograms and the merged sketches."""
    if base is not None:
        sketches.merge(_base_sketches(base, [k for k in stat_keys if k in sketches.values]))
    merged_stats: dict[str, FeatureStats] = {}
    histograms: dict[str, list[int]] = {}
    levels = {f.key: histogram_levels(f.video_info) for f in features if f.video_info is not None}
    for key in stat_keys:
        stacked = parts.stacked(key)
        if base is not None:  # the existing dataset's stats: one more part, the last
            stacked = {
                s: np.concatenate([v, np.asarray(base.stats[key][s])[None]]) for s, v in stacked.items()
            }
        hist = parts.histogram(key)
        if hist is not None and (base is None or key in base.histograms):
            total = hist if base is None else hist + base.histograms[key]
            value = histogram_stats(
                total, int(stacked["count"][:, 0].astype(np.int64).sum()), levels.get(key)
            )
            histograms[key] = total.tolist()
        else:
            value = merge_stacked_stats(stacked)
            if key in sketches.values:  # merged sketches, within the bound of bagport.stats.sketch
                shape = np.shape(value["min"])
                value.update({q: v.reshape(shape) for q, v in sketches.values[key].quantiles().items()})
        merged_stats[key] = value
    merged = {
        key: {stat: np.asarray(v).tolist() for stat, v in value.items()}
        for key, value in merged_stats.items()
    }
    (root / STATS_PATH).write_text(json.dumps(merged, indent=4))
    (root / HISTOGRAMS_PATH).parent.mkdir(parents=True, exist_ok=True)
    (root / HISTOGRAMS_PATH).write_text(json.dumps(histograms))
    sketches.write(root)
    return sketches
