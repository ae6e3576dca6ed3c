"""Convert one bag into a staged episode artifact (see :mod:`bagport.staging`).

The steps, each a library function: :func:`~bagport.episode.prepare.prepare_episode` (the bag fits
the contract, pass 1, alignment), :func:`~bagport.episode.assemble.iter_frames` (pass 2) into
:class:`~bagport.episode.sinks.EpisodeSinks`, :func:`~bagport.episode.quality.assess_episode`, then
the staged files, ``episode.json`` last. ``bagport qa`` (:mod:`bagport.episode.score`) runs the same
steps with QA's value monitor as the only sink.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import pyarrow as pa
from fsspec.core import url_to_fs

from bagport import __version__
from bagport.bags import open_bag, source_stamp
from bagport.contract import ContractPlan, FeatureKind, parse_contract
from bagport.data_table import episode_data_bytes
from bagport.episode.alignment import Alignment
from bagport.episode.assemble import iter_frames
from bagport.episode.checks import bag_fingerprint
from bagport.episode.fidelity import EpisodeFidelity
from bagport.episode.prepare import PreparedEpisode, prepare_episode
from bagport.episode.publish import publish_episode
from bagport.episode.quality import assess_episode, bag_checks
from bagport.episode.reuse import ReusedClip, clip_keys, find_reusable_clips
from bagport.episode.sinks import EpisodeSinks, write_provenance
from bagport.episode.staged import PlannedEpisode, matches
from bagport.episode.tasks import resolve_tasks
from bagport.episode.video import skipped_packet_checks
from bagport.qa import CheckResult, EpisodeQA, QAConfig, ValueMonitor
from bagport.request import EpisodeRequest
from bagport.scratch import clean_dead_scratch, scratch_dir
from bagport.staging import (
    FRAMES_FILE,
    PROVENANCE_FILE,
    QA_FILE,
    STATS_FILE,
    EpisodeSummary,
    StagedFeature,
    episode_dir,
    read_summary,
)
from bagport.video import ClipInfo, EncoderSettings

__all__ = ["convert_episode"]

_SCRATCH_SWEEP_S = 60.0
"""A worker looks for the scratch folders of dead processes at most this often (it lists the temp dir)."""
_last_sweep_s: list[float] = []


@lru_cache(maxsize=8)
def _contract_plan(text: str, name: str) -> ContractPlan:
    """The parsed contract, once per process for each contract (a worker converts many episodes with one;
    the plan is immutable). An invalid contract raises each time (errors are not cached)."""
    return parse_contract(text, name)


def _sweep_dead_scratch() -> None:
    """A worker on another host cleans after its own killed predecessors: at its first episode, then at
    most every :data:`_SCRATCH_SWEEP_S`."""
    now_s = time.monotonic()
    if _last_sweep_s and now_s - _last_sweep_s[0] < _SCRATCH_SWEEP_S:
        return
    _last_sweep_s[:] = [now_s]
    clean_dead_scratch()


@dataclass(frozen=True, slots=True)
class _Episode:
    """What one conversion decided before streaming: the request, the contract and the prepared bag."""

    request: EpisodeRequest
    plan: ContractPlan
    settings: EncoderSettings
    qa_config: QAConfig
    stamp: str
    prepared: PreparedEpisode
    frame_tasks: list[str]
    task_source: str
    clip_keys: dict[str, str]
    reused: dict[str, ReusedClip]
    """Cameras this contract change does not touch: copied from an earlier staged episode."""
    workdir: Path


def convert_episode(request: EpisodeRequest) -> EpisodeSummary:
    """Read one bag, align it to the fps grid, encode videos, and stage the result.

    Raises a :class:`bagport.errors.BagportError` subclass naming the bag, topic
    and time of any problem; on error nothing is left in the staging store.
    """
    plan = _contract_plan(request.contract_text, request.contract_name)
    settings = request.encoder
    stamp = source_stamp(request.bag_uri)
    reusable = _reusable(request, stamp)
    if reusable is not None:
        return reusable
    _sweep_dead_scratch()
    with open_bag(request.bag_uri, msg_definitions=request.msg_definitions) as whole:
        prepared = prepare_episode(whole, plan, request)
        alignment = prepared.alignment
        frame_tasks, task_source = resolve_tasks(
            prepared.timeline.tasks, alignment.ticks_ns, whole.info.custom_data, request,
            plan.contract.default_task,
        )  # fmt: skip
        keys = clip_keys(request, stamp, plan.fps, alignment)
        workdir = scratch_dir("episode")
        try:
            episode = _Episode(
                request, plan, settings, request.qa,
                stamp, prepared, frame_tasks, task_source, keys, find_reusable_clips(request, keys), workdir,
            )  # fmt: skip
            summary = _stage(episode)
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
    return summary


def _stage(episode: _Episode) -> EpisodeSummary:
    """Stream the episode into its sinks, score it, and publish the staged artifact."""
    plan, workdir, alignment = episode.plan, episode.workdir, episode.prepared.alignment
    monitor = ValueMonitor(episode.qa_config.values, plan.fps, alignment.frames)
    gop = episode.settings.g or 1
    fidelity = EpisodeFidelity(episode.qa_config.video, workdir, gop)  # its files go before publishing
    sinks = EpisodeSinks(
        workdir, plan, episode.settings, episode.frame_tasks, monitor, fidelity, episode.request.bag_uri
    )
    features = [f for f in plan.features if f.key not in episode.reused]
    try:
        for frame in iter_frames(
            episode.prepared.reader,
            episode.request.bag_uri,
            features,
            alignment.of({f.key for f in features}),  # a reused camera is not even read
            alignment.ticks_ns,
            plan.source_name,
            episode.prepared.whole,
        ):
            sinks.add(frame)
    finally:
        clips = sinks.close()
    qa = _assess(episode, fidelity, clips, monitor)
    (workdir / QA_FILE).write_text(json.dumps(qa.to_dict()))
    write_provenance(workdir / PROVENANCE_FILE, alignment.sources, alignment.ticks_ns)
    staged = _staged_features(plan, alignment, sinks, clips, episode.reused)
    stats = sinks.stats([f.key for f in staged if f.video_info is None])
    stats.update({key: clip.stats for key, clip in episode.reused.items()})
    (workdir / STATS_FILE).write_text(json.dumps(stats))
    in_hand = sinks.frames.written_table()
    frames = in_hand if in_hand is not None else str(workdir / FRAMES_FILE)
    summary = _summary(episode, staged, qa, frames)
    publish_episode(workdir, summary.dir_uri, summary)
    return summary


def _assess(
    episode: _Episode, fidelity: EpisodeFidelity, clips: dict[str, ClipInfo], monitor: ValueMonitor
) -> EpisodeQA:
    """The episode's QA: :func:`bag_checks`, the video checks of its clips, then every streamed check."""
    prepared, config, fps = episode.prepared, episode.qa_config, episode.plan.fps
    video_checks, video_plots = fidelity.check(clips, fps)  # before publishing: refs are scratch
    extra_plots = _take_reused(episode.workdir, episode.reused, video_checks, video_plots, monitor)
    skipped = {
        t.topic: t.skipped_packets for t in prepared.timeline.topics.values() if t.skipped_packets is not None
    }
    extra = [
        *bag_checks(prepared.reader, config, prepared.alignment, episode.frame_tasks),
        *video_checks,
        *skipped_packet_checks(skipped),
    ]
    return assess_episode(
        episode.request.bag_uri, config, prepared.timeline, prepared.alignment, monitor, extra, fps,
        extra_plots=extra_plots,
    )  # fmt: skip


def _summary(
    episode: _Episode, features: tuple[StagedFeature, ...], qa: EpisodeQA, frames: pa.Table | str
) -> EpisodeSummary:
    """The staged episode's record; ``frames``: its frame table in hand, or its path to read back."""
    request, info, alignment = episode.request, episode.prepared.whole.info, episode.prepared.alignment
    ticks = alignment.ticks_ns
    return EpisodeSummary(
        episode_id=request.episode_id,
        dir_uri=episode_dir(request.staging_uri, request.episode_id),
        bag_uri=request.bag_uri,
        storage=str(info.storage),
        bag_size_bytes=info.size_bytes,
        bag_fingerprint=bag_fingerprint(info),
        manifest_entry=request.manifest_entry,
        fps=episode.plan.fps,
        frames=int(ticks.size),
        first_tick_ns=int(ticks[0]),
        last_tick_ns=int(ticks[-1]),
        tasks=tuple(dict.fromkeys(episode.frame_tasks)),
        task_source=episode.task_source,
        features=features,
        stamp_sources={f"{s.src.key}@{s.src.topic}": s.stamp_used for s in alignment.sources},
        videos={f.key: f"videos/{f.key}.mp4" for f in features if f.video_info is not None},
        metadata=dict(request.metadata),
        window_ns=episode.prepared.window_ns,
        segment=request.segment,
        label=request.label,
        note=request.note,
        bagport_version=__version__,
        contract_sha256=request.contract_sha256,
        source_stamp=episode.stamp,
        default_task=request.default_task,
        alignment=list(alignment.report),
        qa=qa_brief(qa),
        qa_sha256=request.qa_sha256,
        bag_read={**episode.prepared.reader.transfer.to_dict(), "warnings": list(info.warnings)},
        clip_keys=episode.clip_keys,
        reused_clips={key: clip.episode_id for key, clip in episode.reused.items()},
        data_bytes=episode_data_bytes(frames, [f for f in features if f.video_info is None]),
    )


def qa_brief(qa: EpisodeQA) -> dict[str, Any]:
    """The part of an episode's QA the reduce step and the flow need: score, verdict, problems."""
    return {
        "score": qa.score,
        "verdict": qa.verdict,
        "headline": qa.headline(),
        "problems": [
            {"check": c.check, "subject": c.subject, "verdict": c.verdict, "reason": c.reason}
            for c in qa.problems
        ],
    }


def _reusable(request: EpisodeRequest, stamp: str) -> EpisodeSummary | None:
    """A completed staged episode with the request's key (:func:`bagport.episode.staged.matches`).

    The run's plan skips these already (one listing of the staging store); this catches an episode
    staged since, or a direct library call. The current request's facts are put on it.
    """
    if not stamp:
        return None
    existing = read_summary(episode_dir(request.staging_uri, request.episode_id))
    if existing is None or not matches(existing, request, stamp):
        return None
    return PlannedEpisode.of(request).apply(existing)


def _staged_features(
    plan: ContractPlan,
    alignment: Alignment,
    sinks: EpisodeSinks,
    clips: dict[str, ClipInfo],
    reused: dict[str, ReusedClip],
) -> tuple[StagedFeature, ...]:
    out = []
    for feature in plan.features:
        mine = alignment.of({feature.key})
        topics = tuple(s.src.topic for s in mine)
        if feature.key in reused:
            out.append(replace(reused[feature.key].feature, sources=topics))
            continue
        if feature.kind is FeatureKind.VIDEO:
            clip = clips[feature.key]
            camera = sinks.cameras[feature.key]
            video_info = camera.video_info(clip, plan.fps)
            shape = (clip.height, clip.width, camera.channels)
            out.append(
                StagedFeature(
                    feature.key, "video", shape, ("height", "width", "channels"), video_info, topics
                )
            )
            continue
        names = sinks.names.get(feature.key, ())
        width = sinks.widths[feature.key]
        out.append(
            StagedFeature(
                feature.key, feature.dtype, (width,), names if len(names) == width else None, None, topics
            )
        )
    return tuple(out)


def _take_reused(
    workdir: Path,
    reused: dict[str, ReusedClip],
    video_checks: list[CheckResult],
    video_plots: dict[str, Any],
    monitor: ValueMonitor,
) -> dict[str, Any]:
    """Copy the reused clips into the episode and add their QA results; returns the extra QA plots."""
    plots: dict[str, Any] = {}
    for key, clip in reused.items():
        fs, path = url_to_fs(clip.clip_uri)
        fs.get_file(path, str(workdir / "videos" / f"{key}.mp4"))
        video_checks.extend(clip.checks)
        if clip.fidelity_plot is not None:
            video_plots[key] = clip.fidelity_plot
    if video_plots:
        plots["fidelity"] = video_plots
    means = {key: clip.image_means for key, clip in reused.items() if clip.image_means is not None}
    if means:
        plots["image_means"] = {**monitor.plots()["image_means"], **means}
    return plots
