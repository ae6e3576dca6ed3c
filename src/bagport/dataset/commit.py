"""The commit of a dataset write: ``meta/`` from the file writers' small results, then the publish.

It never opens a data or video file: the placements, task counts, sizes and digests come from the
:class:`~bagport.dataset.files.WrittenFile` results, the stats from the staged summaries and
``stats.json`` files; its memory and time grow with the number of episodes (an append: the new ones).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from fsspec.core import url_to_fs

from bagport.dataset.base import DatasetBase, read_info
from bagport.dataset.crashpoints import reached
from bagport.dataset.data_files import DataPlacement
from bagport.dataset.files import WrittenFile
from bagport.dataset.free_memory import release_unused_memory
from bagport.dataset.meta import EpisodeStats, build_info, load_episode_stats, write_meta
from bagport.dataset.provenance import write_provenance
from bagport.dataset.publish import commit_append, swap_into_place
from bagport.dataset.qa import add_fleet_checks
from bagport.dataset.remote import publish_staged
from bagport.dataset.run_meta import finish_meta
from bagport.dataset.session import WriteSession
from bagport.dataset.sketches import DatasetSketches
from bagport.dataset.videos import VideoPlacement
from bagport.errors import DatasetWriteError
from bagport.qa import QABrief, QAEntry
from bagport.scratch import scratch_folder
from bagport.staging import EpisodeSummary

__all__ = ["DatasetReport", "commit_write"]


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
    """Episodes this run converted (a bag that failed to is in :attr:`excluded`); the others came from the
    staging store as they were."""
    reused: tuple[str, ...] = ()
    """Episodes taken from the staging store without converting them again (bag URI, ``#<n>`` for a split bag)."""
    outputs: dict[str, str] = field(default_factory=dict)
    """Every format the run wrote (``--format``): format -> its output (:mod:`bagport.formats`)."""


@dataclass(frozen=True, slots=True)
class Placed:
    """Where each kept episode went, gathered from the file writers' results."""

    data: list[DataPlacement]
    task_indices: list[npt.NDArray[np.int64]]
    videos: dict[str, list[VideoPlacement]]
    digests: dict[str, str]
    size_bytes: int


def gather(session: WriteSession, written: Sequence[WrittenFile], episodes: int) -> Placed:
    """The per-episode placements of every planned file (each must have been written once)."""
    if sorted(w.item.name for w in written) != sorted(item.name for item in session.plan.files):
        raise DatasetWriteError(
            f"the files written do not match the plan of {session.output}; nothing was written."
        )
    keys = [f.key for f in session.features if f.video_info is not None]
    videos: dict[str, list[VideoPlacement | None]] = {key: [None] * episodes for key in keys}
    data: list[DataPlacement | None] = [None] * episodes
    counts: list[tuple[tuple[int, int], ...]] = [()] * episodes
    for result in written:
        for position, placed, pairs in zip(
            result.item.episodes, result.data, result.task_counts, strict=False
        ):
            data[position], counts[position] = placed, pairs
        for position, video in zip(result.item.episodes, result.videos, strict=False):
            videos[result.item.key][position] = video
    missing = [n for n, placed in enumerate(data) if placed is None]
    if missing:  # a writer's result without one of its episodes: never a dataset with rows out of place
        raise DatasetWriteError(
            f"no data file holds kept episode(s) at position(s) {missing[:5]} of this run; nothing was "
            "published. This is a bug in bagport's file plan: please report it with the run's log."
        )
    task_indices = [
        np.repeat(np.array([i for i, _ in pairs], dtype=np.int64), [n for _, n in pairs]) for pairs in counts
    ]
    digests = {rel: digest for w in written for rel, _, digest in w.files}
    size = sum(size for w in written for _, size, _ in w.files)
    complete = {key: [p for p in placed if p is not None] for key, placed in videos.items()}
    return Placed([p for p in data if p is not None], task_indices, complete, digests, size)


def _build_meta(
    root: Path,
    session: WriteSession,
    summaries: Sequence[EpisodeSummary],
    placed: Placed,
    base: DatasetBase | None,
    robot_type: str,
    extras: tuple[dict[str, Any], Sequence[QAEntry], dict[str, Any]],
) -> DatasetReport:
    """Write ``meta/`` (and the provenance, QA and checksums) under ``root``."""
    run_record, qa, qa_config = extras
    plan = session.plan
    sketches = DatasetSketches()  # the new episodes' quantile and step sketches, merged as they load
    steps: list[EpisodeStats] = []  # each episode's largest steps only (the jump check's input)

    def episode_stats() -> Iterator[EpisodeStats]:
        for i, s in enumerate(summaries):
            ep = load_episode_stats(
                s, plan.first_episode + i, placed.data[i], placed.task_indices[i], sketches
            )
            steps.append(EpisodeStats({}, {}, ep.largest_steps))
            yield ep

    total_frames = plan.first_index + sum(s.frames for s in summaries)
    info = build_info(
        session.features,
        robot_type=robot_type,
        fps=plan.fps,
        total_episodes=plan.first_episode + len(summaries),
        total_frames=total_frames,
        total_tasks=len(plan.tasks),
        limits=plan.limits,
    )
    if base is not None:
        check_same_features(base, info)
    meta = (session.features, plan.tasks, placed.data, placed.videos)
    sketches = write_meta(root, summaries, *meta, episode_stats(), info, sketches, base)
    release_unused_memory()
    qa = add_fleet_checks(qa, steps, sketches, session.features, qa_config, plan.fps)  # jumps vs the fleet
    write_provenance(root, summaries, placed.data, run_record, base, record=False)  # the record: last
    release_unused_memory()
    entries, qa_report = finish_meta(
        root, session, summaries, qa, qa_config, base, robot_type, placed.digests, run_record
    )
    briefs = tuple(e.brief() for e in entries)
    excluded = tuple(e.brief() for e in entries if e.episode_index is None)
    episodes, duration_s = int(info["total_episodes"]), total_frames / plan.fps
    return DatasetReport(
        session.output,
        episodes,
        total_frames,
        plan.tasks,
        tuple(placed.videos),
        0,
        duration_s,
        excluded,
        briefs,
        qa_report,
    )


def check_same_features(base: DatasetBase, info: dict[str, Any]) -> None:
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


def _total_episodes(output: str) -> int:
    url_to_fs(output)[0].invalidate_cache()
    return int(read_info(output)["total_episodes"])


def _meta_size(root: Path) -> int:
    return sum(p.stat().st_size for p in (root / "meta").rglob("*") if p.is_file())


def commit_write(
    session: WriteSession,
    summaries: Sequence[EpisodeSummary],
    written: Sequence[WrittenFile],
    *,
    robot_type: str,
    run_record: dict[str, Any] | None = None,
    qa: Sequence[QAEntry] = (),
    qa_config: dict[str, Any] | None = None,
) -> DatasetReport:
    """Write ``meta/`` from the written files' results and publish the write (see the module docstring)."""
    base = session.base
    if base is not None and _total_episodes(session.output) != base.episodes:
        raise DatasetWriteError(
            f"{session.output} changed during the append (it had {base.episodes} episodes when the append "
            "started); nothing was written. Fix: run the append again (one append at a time per dataset)."
        )
    placed = gather(session, written, len(summaries))
    extras = (run_record or {}, qa, qa_config or {})
    final = Path(url_to_fs(session.output)[1])
    if session.remote:
        with scratch_folder("meta") as scratch:
            report = _build_meta(scratch, session, summaries, placed, base, robot_type, extras)
            publish_staged(
                scratch, session.output, session.staged, placed.digests,
                append=base is not None, overwrite=session.overwrite,
            )  # fmt: skip
        fs, root = url_to_fs(session.output)
        fs.invalidate_cache()
        return _sized(report, int(fs.du(root)))
    build = Path(session.build)
    if base is None:
        reached("local.publish.files")
    else:
        reached("local.append.files")
    report = _build_meta(build, session, summaries, placed, base, robot_type, extras)
    size = placed.size_bytes + _meta_size(build)
    if base is None:
        swap_into_place(build, final, overwrite=session.overwrite)
        return _sized(report, size)
    commit_append(build, final, sorted(placed.digests))
    return _sized(report, sum(p.stat().st_size for p in final.rglob("*") if p.is_file()))


def _sized(report: DatasetReport, size: int) -> DatasetReport:
    return replace(report, size_bytes=size)
