"""The reduce step: staged episodes in, one LeRobot v3.0 dataset out, published atomically."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.base import DatasetBase, read_base
from bagport.dataset.checksums import record_checksums
from bagport.dataset.data_files import write_data_files
from bagport.dataset.meta import DatasetLimits, build_info, load_episode_stats, write_meta
from bagport.dataset.provenance import run_record_path, write_provenance
from bagport.dataset.publish import building_beside, commit_append
from bagport.dataset.qa import add_fleet_checks, write_qa
from bagport.dataset.remote import append_remote
from bagport.dataset.repair import repair_dataset
from bagport.dataset.replace import publish_built, refuse_existing
from bagport.dataset.sketches import DatasetSketches
from bagport.dataset.videos import write_video_files
from bagport.errors import DatasetWriteError
from bagport.qa import QABrief, QAEntry
from bagport.scratch import scratch_folder
from bagport.staging import FRAMES_FILE, EpisodeSummary, StagedFeature
from bagport.uris import is_local

__all__ = ["DatasetReport", "write_dataset"]


@dataclass(frozen=True, slots=True)
class DatasetReport:
    root: str
    episodes: int
    frames: int
    tasks: tuple[str, ...]
    video_keys: tuple[str, ...]
    size_bytes: int
    duration_s: float
    excluded: tuple[QABrief, ...] = ()
    """Bags left out (QA failure or conversion error), with the reason."""
    qa: tuple[QABrief, ...] = ()
    """Every bag's QA brief: episode index (None when excluded), score, verdict, reason."""
    qa_report: str | None = None
    """The HTML QA report in the dataset (``meta/qa/report.html``: every run, rebuilt by each one)."""
    converted: int = 0
    """Episodes this run converted (or tried to); the others came from the staging store as they were."""
    reused: tuple[str, ...] = ()
    """Episodes taken from the staging store without converting them again (bag URI, ``#<n>`` for a split bag)."""
    outputs: dict[str, str] = field(default_factory=dict)
    """Every format the run wrote (``--format``): format -> its output (:mod:`bagport.formats`)."""


def _check_consistent(summaries: Sequence[EpisodeSummary]) -> tuple[StagedFeature, ...]:
    if not summaries:
        raise DatasetWriteError("no episode to write: every bag failed or the manifest is empty.")
    reference = summaries[0]
    for summary in summaries[1:]:
        if summary.fps != reference.fps:
            raise DatasetWriteError(
                f"{summary.bag_uri} was converted at {summary.fps} fps, {reference.bag_uri} at {reference.fps}"
            )
        mine = {f.key: f for f in summary.features}
        for feature in reference.features:
            other = mine.get(feature.key)
            if other is None:
                raise DatasetWriteError(
                    f"{summary.bag_uri} has no feature {feature.key!r} but {reference.bag_uri} has"
                )
            if (other.dtype, other.shape, other.names) != (feature.dtype, feature.shape, feature.names):
                raise DatasetWriteError(
                    f"feature {feature.key!r} differs between bags: {reference.bag_uri} gives "
                    f"{feature.dtype}{list(feature.shape)} names={feature.names}, {summary.bag_uri} gives "
                    f"{other.dtype}{list(other.shape)} names={other.names}. Fix: select the same joints/fields "
                    "explicitly with selector.names, and set image.resize so every camera has one size."
                )
            if feature.video_info != other.video_info:
                raise DatasetWriteError(
                    f"video {feature.key!r} was encoded differently in {summary.bag_uri} and {reference.bag_uri} "
                    f"({other.video_info} vs {feature.video_info}); clips can only be joined with identical settings."
                )
    return reference.features


def _task_indices(summary: EpisodeSummary, task_index: dict[str, int]) -> npt.NDArray[np.int64]:
    fs, path = url_to_fs(summary.file(FRAMES_FILE))
    with fs.open(path, "rb") as handle:
        tasks = [str(t) for t in pq.read_table(handle, columns=["task"]).column("task").to_pylist()]
    return np.array([task_index[t] for t in tasks], dtype=np.int64)


def _build(
    root: Path,
    summaries: Sequence[EpisodeSummary],
    robot_type: str,
    limits: DatasetLimits,
    run_record: dict[str, Any],
    qa: Sequence[QAEntry],
    qa_config: dict[str, Any],
    base: DatasetBase | None = None,
) -> DatasetReport:
    """Write the dataset's files under ``root``; with ``base``, only this run's new files plus ``meta/``."""
    features = _check_consistent(summaries)
    fps = summaries[0].fps
    first_episode = base.episodes if base is not None else 0
    first_index = base.frames if base is not None else 0
    known = base.tasks if base is not None else []
    tasks = list(dict.fromkeys([*known, *(t for s in summaries for t in s.tasks)]))
    task_index = {t: i for i, t in enumerate(tasks)}
    vectors = [f for f in features if f.video_info is None]
    video_keys = [f.key for f in features if f.video_info is not None]
    data = write_data_files(
        root,
        summaries,
        vectors,
        task_index,
        file_size_in_mb=limits.data_files_size_in_mb,
        chunks_size=limits.chunks_size,
        start=base.next_data if base is not None else (0, 0),
        first_episode_index=first_episode,
        first_index=first_index,
    )
    videos = {
        key: write_video_files(
            root,
            key,
            summaries,
            fps=fps,
            file_size_in_mb=limits.video_files_size_in_mb,
            chunks_size=limits.chunks_size,
            start=base.next_video.get(key, (0, 0)) if base is not None else (0, 0),
        )
        for key in video_keys
    }
    sketches = DatasetSketches()  # the new episodes' quantile and step sketches, merged as they load
    episode_stats = [
        load_episode_stats(s, first_episode + i, data[i], _task_indices(s, task_index), sketches)
        for i, s in enumerate(summaries)
    ]
    new_frames = sum(s.frames for s in summaries)
    info = build_info(
        features,
        robot_type=robot_type,
        fps=fps,
        total_episodes=first_episode + len(summaries),
        total_frames=first_index + new_frames,
        total_tasks=len(tasks),
        limits=limits,
    )
    if base is not None:
        _check_same_features(base, info)
    sketches = write_meta(root, summaries, features, tasks, data, videos, episode_stats, info, sketches, base)
    qa = add_fleet_checks(qa, episode_stats, sketches, features, qa_config, fps)  # jumps vs the fleet
    write_provenance(root, summaries, data, run_record, base)
    size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    total_frames = first_index + new_frames
    facts = {
        "episodes": first_episode + len(summaries),
        "added by this run": len(summaries),
        "excluded": sum(e.episode_index is None for e in qa),
        "frames": total_frames,
        "duration_s": round(total_frames / fps, 2),
        "fps": fps,
        "tasks": "; ".join(tasks),
    }
    entries = [
        e if e.episode_index is None else replace(e, episode_index=e.episode_index + first_episode)
        for e in qa
    ]
    qa_report = (
        write_qa(
            root,
            entries,
            facts,
            qa_config,
            base.run_number if base is not None else 0,
            robot_type=robot_type,
            names={f.key: f.names for f in features},
        )
        if entries
        else None
    )
    carried = {} if base is None else base.checksums
    record_checksums(root, run_record_path(base), carried)
    return DatasetReport(
        str(root),
        first_episode + len(summaries),
        total_frames,
        tuple(tasks),
        tuple(video_keys),
        size,
        total_frames / fps,
        tuple(e.brief() for e in entries if e.episode_index is None),
        tuple(e.brief() for e in entries),
        qa_report,
    )


def _check_same_features(base: DatasetBase, info: dict[str, Any]) -> None:
    old, new = base.info["features"], info["features"]
    if old == new and base.info["fps"] == info["fps"]:
        return
    changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
    raise DatasetWriteError(
        f"cannot append: the new episodes' features differ from the dataset's ({', '.join(changed) or 'fps'}: "
        f"dataset has {[old.get(k) for k in changed[:2]]}, new episodes give {[new.get(k) for k in changed[:2]]}); "
        "nothing was written. Fix: append with the contract and codec the dataset was made with, or convert "
        "into a new --output."
    )


def write_dataset(
    summaries: Sequence[EpisodeSummary],
    output: str,
    *,
    robot_type: str,
    limits: DatasetLimits | None = None,
    run_record: dict[str, Any] | None = None,
    overwrite: bool = False,
    qa: Sequence[QAEntry] = (),
    qa_config: dict[str, Any] | None = None,
    append: bool = False,
) -> DatasetReport:
    """Write the dataset at ``output`` (the dataset root).

    Whatever a killed run left at ``output`` is repaired first (:mod:`bagport.dataset.repair`). A new
    dataset is built beside a local ``output`` and put in place by one atomic exchange
    (:mod:`bagport.dataset.publish`); on an object store it is built locally and published under an
    intent record (:mod:`bagport.dataset.remote`). With ``append``, the episodes are added to the
    dataset at ``output`` (created if missing) as new files: old data and video files never change.
    """
    limits = limits or DatasetLimits()
    fs, out_path = url_to_fs(output)
    repair_dataset(output)
    fs.invalidate_cache()

    def build(root: Path, base: DatasetBase | None = None, limits: DatasetLimits = limits) -> DatasetReport:
        return _build(root, summaries, robot_type, limits, run_record or {}, qa, qa_config or {}, base)

    if append and fs.exists(out_path):
        if not is_local(fs):
            with scratch_folder("append") as scratch:
                report = append_remote(output, build, scratch)
            return replace(report, root=output, size_bytes=int(fs.du(out_path)))
        return _append(Path(out_path), build)
    refuse_existing(output, overwrite=overwrite)
    report = publish_built(output, build)
    return replace(report, root=output)


def _append(final: Path, build: Callable[[Path, DatasetBase, DatasetLimits], DatasetReport]) -> DatasetReport:
    """Add episodes to the dataset at ``final`` without touching its data and video files: new files and
    a new ``meta/`` are built beside it, then committed (:func:`bagport.dataset.publish.commit_append`)."""
    base = read_base(final)
    with building_beside(final) as build_root:
        shutil.copytree(final / "meta", build_root / "meta")
        report = build(build_root, base, DatasetLimits.from_info(base.info))
        added = [
            p.relative_to(build_root).as_posix()
            for folder in ("data", "videos")
            for p in sorted((build_root / folder).rglob("*"))
            if p.is_file()
        ]
        commit_append(build_root, final, added)
    size = sum(p.stat().st_size for p in final.rglob("*") if p.is_file())
    return replace(report, root=str(final), size_bytes=size)
