"""Check a dataset folder against the LeRobot v3.0 invariants, without LeRobot.

Each check raises :class:`ValidationError` on the first violation with the file
and the exact value that is wrong.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bagport.dataset.layout import CODEBASE_VERSION, DEFAULT_FEATURES, INFO_PATH, STATS_PATH, TASKS_PATH
from bagport.errors import ValidationError, VideoError
from bagport.stats import STAT_KEYS
from bagport.video import probe_video

__all__ = ["DATASET_FIX", "FILE_FIX", "REWRITE", "check_invariants"]

REWRITE = "convert the dataset's bags again into a new --output (or --overwrite this one)"
FILE_FIX = f"restore the file from a backup (or its object store's earlier version), or {REWRITE}."
"""For a file missing, changed or damaged after bagport wrote it."""
DATASET_FIX = f"restore the dataset from a backup, or {REWRITE}."
"""For a dataset whose files disagree with each other or with LeRobot v3.0."""
_V30_FIX = (
    "convert a v2.1 dataset to v3.0 with LeRobot's convert_dataset_v21_to_v30 script (`--root DIR "
    f"--push-to-hub=false`), or {REWRITE}."
)

_REQUIRED_INFO = (
    "codebase_version",
    "robot_type",
    "fps",
    "features",
    "total_episodes",
    "total_frames",
    "total_tasks",
    "chunks_size",
    "data_files_size_in_mb",
    "video_files_size_in_mb",
    "data_path",
    "video_path",
    "splits",
)
_TIME_TOL_S = 1e-4


def _fail(where: Path | str, what: str, fix: str = DATASET_FIX) -> ValidationError:
    return ValidationError(what, path=where, fix=fix)


def _load_info(root: Path) -> dict[str, Any]:
    path = root / INFO_PATH
    if not path.is_file():
        raise _fail(
            path,
            "missing: this is not a LeRobot v3.0 dataset folder",
            "give the dataset's root folder (the one holding meta/info.json), or restore info.json from a backup.",
        )
    info: dict[str, Any] = json.loads(path.read_text())
    missing = [k for k in _REQUIRED_INFO if k not in info]
    if missing:
        raise _fail(path, f"missing fields {missing}")
    if info["codebase_version"] != CODEBASE_VERSION:
        raise _fail(
            path, f"codebase_version is {info['codebase_version']!r}, expected {CODEBASE_VERSION!r}", _V30_FIX
        )
    for stale in ("total_chunks", "total_videos"):
        if stale in info:
            raise _fail(path, f"has v2.1 field {stale!r}", _V30_FIX)
    for key, feature in info["features"].items():
        if "/" in key or any("/" in str(n) for n in (feature.get("names") or [])):
            raise _fail(path, f"feature {key!r}: names must not contain '/'")
        for field in ("dtype", "shape", "names"):
            if field not in feature:
                raise _fail(path, f"feature {key!r} lacks {field!r}")
    for key, feature in DEFAULT_FEATURES.items():
        if info["features"].get(key, {}).get("dtype") != feature["dtype"]:
            raise _fail(path, f"default feature {key!r} missing or not {feature['dtype']}")
    return info


Row = dict[str, Any]


def _check_episode_rows(root: Path, info: dict[str, Any], episodes: list[Row]) -> None:
    fps = int(info["fps"])
    where = root / "meta/episodes"
    if [row["episode_index"] for row in episodes] != list(range(len(episodes))):
        raise _fail(where, "episode_index is not 0..N-1 in order")
    if len(episodes) != info["total_episodes"]:
        raise _fail(where, f"{len(episodes)} episodes but info.total_episodes={info['total_episodes']}")
    expected_from = 0
    video_keys = [k for k, f in info["features"].items() if f["dtype"] == "video"]
    for row in episodes:
        ep = row["episode_index"]
        start, stop, length = row["dataset_from_index"], row["dataset_to_index"], row["length"]
        if start != expected_from or stop - start != length or length <= 0:
            raise _fail(
                where, f"episode {ep}: index range [{start}, {stop}) length {length} is not contiguous"
            )
        expected_from = stop
        for key in video_keys:
            span = (row[f"videos/{key}/to_timestamp"] - row[f"videos/{key}/from_timestamp"]) * fps
            if abs(span - length) > 1e-3:
                raise _fail(where, f"episode {ep}: videos/{key} spans {span:.4f} frames, length is {length}")
    if expected_from != info["total_frames"]:
        raise _fail(where, f"episodes cover {expected_from} frames, info.total_frames={info['total_frames']}")


def _group(episodes: list[Row], *columns: str) -> dict[tuple[int, ...], list[Row]]:
    groups: dict[tuple[int, ...], list[Row]] = {}
    for row in episodes:
        groups.setdefault(tuple(int(row[c]) for c in columns), []).append(row)
    return dict(sorted(groups.items()))


def _check_data(root: Path, info: dict[str, Any], episodes: list[Row]) -> None:
    fps = int(info["fps"])
    columns = [k for k, f in info["features"].items() if f["dtype"] not in ("video", "image")]
    for (chunk, file), group in _group(episodes, "data/chunk_index", "data/file_index").items():
        path = root / info["data_path"].format(chunk_index=chunk, file_index=file)
        if not path.is_file():
            raise _fail(
                path, f"missing (referenced by episodes {[r['episode_index'] for r in group]})", FILE_FIX
            )
        table = _read_parquet(path)
        extra = set(table.column_names) - set(columns)
        absent = set(columns) - set(table.column_names)
        if extra or absent:
            raise _fail(
                path,
                f"columns differ from info.features: undeclared {sorted(extra)}, missing {sorted(absent)}",
            )
        ep_col = table.column("episode_index").to_numpy()
        for row in group:
            ep = row["episode_index"]
            frames = table.filter(pa.array(ep_col == ep))
            n = frames.num_rows
            if n != row["length"]:
                raise _fail(path, f"episode {ep} has {n} rows, meta says {row['length']}")
            if not np.array_equal(frames.column("frame_index").to_numpy(), np.arange(n)):
                raise _fail(path, f"episode {ep}: frame_index is not 0..{n - 1}")
            expected_index = np.arange(row["dataset_from_index"], row["dataset_to_index"])
            if not np.array_equal(frames.column("index").to_numpy(), expected_index):
                raise _fail(path, f"episode {ep}: index is not {row['dataset_from_index']}..")
            ts = frames.column("timestamp").to_numpy()
            expected = (np.arange(n) / fps).astype(np.float32)
            if not np.allclose(ts, expected, atol=_TIME_TOL_S, rtol=0):
                k = int(np.argmax(np.abs(ts - expected)))
                raise _fail(path, f"episode {ep} frame {k}: timestamp {ts[k]} != {k}/{fps}")
            tasks = frames.column("task_index").to_numpy()
            if tasks.min() < 0 or tasks.max() >= info["total_tasks"]:
                raise _fail(path, f"episode {ep}: task_index outside 0..{info['total_tasks'] - 1}")


def _check_videos(root: Path, info: dict[str, Any], episodes: list[Row]) -> None:
    fps = int(info["fps"])
    for key, feature in info["features"].items():
        if feature["dtype"] != "video":
            continue
        for (chunk, file), group in _group(
            episodes, f"videos/{key}/chunk_index", f"videos/{key}/file_index"
        ).items():
            path = root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
            if not path.is_file():
                raise _fail(
                    path, f"missing (referenced by episodes {[r['episode_index'] for r in group]})", FILE_FIX
                )
            try:
                probed = probe_video(path)
            except VideoError as err:  # its cause is FFmpeg's own error
                raise _fail(path, f"is not a readable video ({err.__cause__ or err})", FILE_FIX) from err
            vinfo = feature.get("info", {})
            if (probed.height, probed.width) != (vinfo.get("video.height"), vinfo.get("video.width")):
                raise _fail(
                    path,
                    f"is {probed.width}x{probed.height}, info says {vinfo.get('video.width')}x{vinfo.get('video.height')}",
                )
            if probed.codec != vinfo.get("video.codec"):
                raise _fail(path, f"codec {probed.codec!r}, info says {vinfo.get('video.codec')!r}")
            needed = round(max(r[f"videos/{key}/to_timestamp"] for r in group) * fps)
            if probed.frames < needed:
                raise _fail(path, f"has {probed.frames} frames, episodes need {needed}")


def _check_stats(root: Path, info: dict[str, Any]) -> None:
    path = root / STATS_PATH
    if not path.is_file():
        raise _fail(path, "missing", FILE_FIX)
    stats = json.loads(path.read_text())
    for key, feature in info["features"].items():
        if key not in stats:
            raise _fail(path, f"no stats for feature {key!r}")
        for stat in STAT_KEYS:
            if stat not in stats[key]:
                raise _fail(path, f"{key}: missing {stat!r}")
            value = np.asarray(stats[key][stat])
            if not np.all(np.isfinite(value)):
                raise _fail(path, f"{key}/{stat} is not finite")
            if stat == "count":
                continue
            channels = feature["shape"][2] if feature["dtype"] == "video" else 0
            if feature["dtype"] == "video" and value.shape != (channels, 1, 1):
                raise _fail(path, f"{key}/{stat} has shape {value.shape}, expected ({channels}, 1, 1)")
            if feature["dtype"] != "video" and value.shape != tuple(feature["shape"]):
                raise _fail(
                    path, f"{key}/{stat} has shape {value.shape}, feature shape is {feature['shape']}"
                )


def _read_parquet(path: Path) -> pa.Table:
    """``path``'s table; a file that is not readable parquet (damaged, truncated) is a :class:`ValidationError`."""
    try:
        return pq.read_table(path)
    except (pa.ArrowException, OSError) as err:
        raise _fail(
            path, f"is not a readable parquet file ({err}): it was damaged after it was written", FILE_FIX
        ) from err


def check_invariants(root: Path) -> dict[str, Any]:
    """Raise on the first violated invariant; returns info.json on success."""
    info = _load_info(root)
    tasks_path = root / TASKS_PATH
    if not tasks_path.is_file():
        raise _fail(tasks_path, "missing", FILE_FIX)
    tasks = _read_parquet(tasks_path).to_pandas()
    if list(tasks["task_index"]) != list(range(len(tasks))) or len(tasks) != info["total_tasks"]:
        raise _fail(tasks_path, f"task_index must be 0..{info['total_tasks'] - 1}")
    episode_files = sorted((root / "meta/episodes").glob("chunk-*/file-*.parquet"))
    if not episode_files:
        raise _fail(root / "meta/episodes", "no episodes parquet", FILE_FIX)
    episodes: list[Row] = []
    for episode_file in episode_files:
        episodes.extend(_read_parquet(episode_file).to_pylist())
    _check_episode_rows(root, info, episodes)
    _check_data(root, info, episodes)
    _check_videos(root, info, episodes)
    _check_stats(root, info)
    return info
