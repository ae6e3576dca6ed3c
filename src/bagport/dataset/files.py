"""The reduce as a map: plan the output files, then write each one on its own (any process, any order).

:func:`plan_files` decides, from the staged summaries and clip sizes alone, which episodes go to which
video file per camera (LeRobot's size rule) and where the data files start; :func:`write_planned_file`
writes one planned item from the staging store into the build location and returns a small
:class:`WrittenFile` (paths, sizes, SHA-256, the per-episode placements ``meta/`` needs). The commit
(:mod:`bagport.dataset.write`) then reads only these results and the staged summaries and stats.

Data files are one item: LeRobot rotates them by their size on disk as they are written. That size is
the sum of the episodes' encoded row groups (a row group's bytes do not depend on where in the file it
goes), but an episode's row group bytes depend on its final ``index`` values (snappy over them: a few
bytes either way), so an exact plan would have to encode every episode's table once more before the
write, reading every staged frame table; a plan from staged sizes or a bytes-per-row bound would not be
LeRobot's rule (docs/fleet.md). They hold no video (a small share of the bytes). Each video file is an item.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from fsspec.core import url_to_fs

from bagport.dataset.data_files import DataPlacement, write_data_files
from bagport.dataset.journal import file_sha256
from bagport.dataset.layout import VIDEO_PATH
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.videos import VideoPlacement, plan_video_files, write_video_file
from bagport.scratch import scratch_folder
from bagport.staging import FRAMES_FILE, EpisodeSummary, StagedFeature
from bagport.uris import is_local

__all__ = ["FilePlan", "PlannedFile", "WrittenFile", "plan_files", "staged_clip_sizes", "write_planned_file"]


@dataclass(frozen=True, slots=True)
class PlannedFile:
    kind: Literal["data", "video"]
    key: str
    """The camera key of a video file ("" for the data files)."""
    chunk_file: tuple[int, int]
    """Where the file goes (data: the first data file, the next ones follow by size)."""
    episodes: tuple[int, ...]
    """Positions of the episodes in the run's kept episodes, in order."""
    inputs: tuple[str, ...]
    """The staged file each episode contributes (``frames.parquet`` or the camera's clip), by URI."""

    @property
    def name(self) -> str:
        """A short label for logs and task runs."""
        if self.kind == "data":
            return f"data from chunk-{self.chunk_file[0]:03d}/file-{self.chunk_file[1]:03d}"
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
    """(path relative to the dataset root, size in bytes, SHA-256) of each file written."""
    data: tuple[DataPlacement, ...] = ()
    task_counts: tuple[tuple[tuple[int, int], ...], ...] = ()
    """Per episode of a data item: (task index, frames) pairs."""
    videos: tuple[VideoPlacement, ...] = ()


def staged_clip_sizes(summaries: Sequence[EpisodeSummary], keys: Sequence[str]) -> dict[str, list[int]]:
    """Per camera: each episode's staged clip size in bytes (one metadata request per clip)."""
    sizes: dict[str, list[int]] = {key: [] for key in keys}
    for summary in summaries:
        for key in keys:
            fs, path = url_to_fs(summary.file(summary.videos[key]))
            sizes[key].append(int(fs.size(path)))
    return sizes


def plan_files(
    summaries: Sequence[EpisodeSummary],
    features: Sequence[StagedFeature],
    tasks: Sequence[str],
    limits: DatasetLimits,
    clip_sizes: Mapping[str, Sequence[int]],
    *,
    next_data: tuple[int, int] = (0, 0),
    next_video: Mapping[str, tuple[int, int]] | None = None,
    first_episode: int = 0,
    first_index: int = 0,
) -> FilePlan:
    """Which episodes go to which output file (pure: no I/O). ``next_*`` and ``first_*`` continue a
    dataset (an append's base)."""
    everyone = tuple(range(len(summaries)))
    planned = [PlannedFile("data", "", next_data, everyone, tuple(s.file(FRAMES_FILE) for s in summaries))]
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
    if item.kind == "data":
        written = write_data_files(
            root,
            item.inputs,
            plan.vectors,
            {t: i for i, t in enumerate(plan.tasks)},
            file_size_in_mb=plan.limits.data_files_size_in_mb,
            chunks_size=plan.limits.chunks_size,
            start=item.chunk_file,
            first_episode_index=plan.first_episode,
            first_index=plan.first_index,
        )
        files = _described(root, written.files)
        return WrittenFile(item, files, data=written.placements, task_counts=written.task_counts)
    rel = VIDEO_PATH.format(video_key=item.key, chunk_index=item.chunk_file[0], file_index=item.chunk_file[1])
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
