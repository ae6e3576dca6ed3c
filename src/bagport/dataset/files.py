"""The reduce as a map: plan the output files, then write each one on its own (any process, any order).

:func:`plan_files` decides, from the staged summaries and sizes alone, which episodes go to which data
file and which video file per camera, by LeRobot's size rules; :func:`write_planned_file` writes one
planned file from the staging store into the build location and returns a small :class:`WrittenFile`
(paths, sizes, SHA-256, the per-episode placements ``meta/`` needs). The commit
(:mod:`bagport.dataset.write`) then reads only these results and the staged summaries and stats.

A video file's episodes follow from the staged clips' sizes (one metadata request per clip: a remux keeps
them). A data file's follow from each episode's row-group bytes, which the worker measured when it staged
the episode (``EpisodeSummary.data_bytes``: the episode's table encoded as the data file encodes it, with
indices from 0; its final ``index`` values change the size by a few bytes), under LeRobot's data rule
(:func:`~bagport.dataset.data_files.plan_data_files`); the episode and global indices of each data file
follow from the frame counts, so no data file waits for another (docs/fleet.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import accumulate
from pathlib import Path
from typing import Literal

from fsspec.core import url_to_fs

from bagport.dataset.data_files import DataPlacement, plan_data_files, write_data_file
from bagport.dataset.journal import file_sha256
from bagport.dataset.layout import DATA_PATH, VIDEO_PATH
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.videos import VideoPlacement, plan_video_files, write_video_file
from bagport.scratch import scratch_folder
from bagport.staging import FRAMES_FILE, EpisodeSummary, StagedFeature
from bagport.uris import is_local

__all__ = [
    "FilePlan",
    "PlannedFile",
    "WrittenFile",
    "plan_files",
    "staged_clip_sizes",
    "staged_data_sizes",
    "write_planned_file",
]


@dataclass(frozen=True, slots=True)
class PlannedFile:
    kind: Literal["data", "video"]
    key: str
    """The camera key of a video file ("" for the data files)."""
    chunk_file: tuple[int, int]
    """Where the file goes."""
    episodes: tuple[int, ...]
    """Positions of the episodes in the run's kept episodes, in order."""
    inputs: tuple[str, ...]
    """The staged file each episode contributes (``frames.parquet`` or the camera's clip), by URI."""
    first_index: int = 0
    """A data file: the global ``index`` of its first frame."""

    @property
    def name(self) -> str:
        """The file's path in the dataset (its label in logs and task runs too)."""
        if self.kind == "data":
            return DATA_PATH.format(chunk_index=self.chunk_file[0], file_index=self.chunk_file[1])
        return VIDEO_PATH.format(
            video_key=self.key, chunk_index=self.chunk_file[0], file_index=self.chunk_file[1]
        )


@dataclass(frozen=True, slots=True)
class FilePlan:
    files: tuple[PlannedFile, ...]
    vectors: tuple[StagedFeature, ...]
    tasks: tuple[str, ...]
    """Every task of the dataset after this run, in task-index order."""
    fps: int
    first_episode: int
    first_index: int
    limits: DatasetLimits


@dataclass(frozen=True, slots=True)
class WrittenFile:
    item: PlannedFile
    files: tuple[tuple[str, int, str], ...]
    """(path relative to the dataset root, size in bytes, SHA-256) of the file written."""
    data: tuple[DataPlacement, ...] = ()
    task_counts: tuple[tuple[tuple[int, int], ...], ...] = ()
    """Per episode of a data file: (task index, frames) pairs."""
    videos: tuple[VideoPlacement, ...] = ()


def _staged_size(summary: EpisodeSummary, rel: str) -> int:
    """One staged file's size in bytes (one metadata request)."""
    fs, path = url_to_fs(summary.file(rel))
    return int(fs.size(path))


def staged_clip_sizes(summaries: Sequence[EpisodeSummary], keys: Sequence[str]) -> dict[str, list[int]]:
    """Per camera: each episode's staged clip size in bytes (one metadata request per clip)."""
    return {key: [_staged_size(summary, summary.videos[key]) for summary in summaries] for key in keys}


def staged_data_sizes(summaries: Sequence[EpisodeSummary]) -> list[int]:
    """Each episode's row-group bytes in a data file, as its worker measured them; for an episode staged
    before bagport recorded them, its staged ``frames.parquet`` size (one metadata request: a rougher
    estimate, without the ``index`` column)."""
    return [
        summary.data_bytes if summary.data_bytes is not None else _staged_size(summary, FRAMES_FILE)
        for summary in summaries
    ]


def plan_files(
    summaries: Sequence[EpisodeSummary],
    features: Sequence[StagedFeature],
    tasks: Sequence[str],
    limits: DatasetLimits,
    clip_sizes: Mapping[str, Sequence[int]],
    data_sizes: Sequence[int],
    *,
    next_data: tuple[int, int] = (0, 0),
    next_video: Mapping[str, tuple[int, int]] | None = None,
    first_episode: int = 0,
    first_index: int = 0,
) -> FilePlan:
    """Which episodes go to which output file (pure: no I/O). ``data_sizes``: each episode's row-group
    bytes (:func:`staged_data_sizes`); ``next_*`` and ``first_*`` continue a dataset (an append's base)."""
    frames = [s.frames for s in summaries]
    starts = list(accumulate(frames, initial=first_index))  # each episode's first global index
    planned = [
        PlannedFile(
            "data",
            "",
            chunk_file,
            tuple(ns),
            tuple(summaries[n].file(FRAMES_FILE) for n in ns),
            starts[ns[0]],
        )
        for chunk_file, ns in plan_data_files(
            data_sizes,
            frames,
            file_size_in_mb=limits.data_files_size_in_mb,
            chunks_size=limits.chunks_size,
            start=next_data,
        )
    ]
    for key in (f.key for f in features if f.video_info is not None):
        groups = plan_video_files(
            clip_sizes[key],
            file_size_in_mb=limits.video_files_size_in_mb,
            chunks_size=limits.chunks_size,
            start=(next_video or {}).get(key, (0, 0)),
        )
        for chunk_file, positions in groups:
            inputs = tuple(summaries[n].file(summaries[n].videos[key]) for n in positions)
            planned.append(PlannedFile("video", key, chunk_file, tuple(positions), inputs))
    return FilePlan(
        files=tuple(planned),
        vectors=tuple(f for f in features if f.video_info is None),
        tasks=tuple(tasks),
        fps=summaries[0].fps,
        first_episode=first_episode,
        first_index=first_index,
        limits=limits,
    )


def _write_local(plan: FilePlan, item: PlannedFile, root: Path) -> WrittenFile:
    rel = item.name
    if item.kind == "data":
        written = write_data_file(
            root / rel,
            item.inputs,
            plan.vectors,
            {t: i for i, t in enumerate(plan.tasks)},
            chunk_file=item.chunk_file,
            first_episode_index=plan.first_episode + item.episodes[0],
            first_index=item.first_index,
        )
        return WrittenFile(
            item, _described(root, [rel]), data=written.placements, task_counts=written.task_counts
        )
    videos = write_video_file(root / rel, item.inputs, fps=plan.fps, chunk_file=item.chunk_file)
    return WrittenFile(item, _described(root, [rel]), videos=tuple(videos))


def _described(root: Path, rels: Sequence[str]) -> tuple[tuple[str, int, str], ...]:
    return tuple((rel, (root / rel).stat().st_size, file_sha256(root / rel)) for rel in rels)


def write_planned_file(plan: FilePlan, item: PlannedFile, build: str) -> WrittenFile:
    """Write one planned item into ``build`` (the build folder, or an object-store prefix the files are
    uploaded to, each as soon as it is complete); reads only the staged files the item names."""
    fs, build_path = url_to_fs(build)
    if is_local(fs):
        return _write_local(plan, item, Path(build_path))
    with scratch_folder("file") as scratch:
        written = _write_local(plan, item, scratch)
        for rel, _, _ in written.files:
            fs.put_file(str(scratch / rel), f"{build_path.rstrip('/')}/{rel}")
            (scratch / rel).unlink()
    return written
