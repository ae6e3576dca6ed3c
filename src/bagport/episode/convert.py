"""Convert one bag into a staged episode artifact (see :mod:`bagport.staging`)."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport import __version__
from bagport.bags import open_bag, source_stamp
from bagport.columns import vector_column
from bagport.contract import ContractPlan, FeatureKind, parse_contract
from bagport.episode.alignment import align_sources
from bagport.episode.assemble import AlignedSource, Frame, assemble_frames
from bagport.episode.cameras import CameraSink
from bagport.episode.checks import bag_fingerprint, scan_episode
from bagport.episode.fidelity import EpisodeFidelity
from bagport.episode.quality import assess_episode, integrity_check, safety_check, task_check
from bagport.episode.reuse import ReusedClip, clip_keys, find_reusable_clips
from bagport.episode.sinks import FrameTableWriter, write_provenance
from bagport.episode.staged import PlannedEpisode, matches
from bagport.episode.tasks import resolve_tasks
from bagport.episode.video import skipped_packet_checks
from bagport.errors import DecodeError
from bagport.qa import CheckResult, EpisodeQA, QAConfig, ValueMonitor
from bagport.request import EpisodeRequest
from bagport.scratch import clean_dead_scratch, scratch_dir
from bagport.staging import (
    EPISODE_SUMMARY,
    FRAMES_FILE,
    PROVENANCE_FILE,
    QA_FILE,
    STATS_FILE,
    EpisodeSummary,
    StagedFeature,
    episode_dir,
    read_summary,
    staged_path,
    write_json,
)
from bagport.stats import episode_sketch_fields, stats_to_json, vector_stats
from bagport.video import EncoderSettings

__all__ = ["convert_episode"]


@dataclass
class _EpisodeSinks:
    workdir: Path
    plan: ContractPlan
    settings: EncoderSettings
    frame_tasks: list[str]
    monitor: ValueMonitor
    fidelity: EpisodeFidelity

    def __post_init__(self) -> None:
        vector_dtypes = {f.key: f.dtype for f in self.plan.features if f.kind is FeatureKind.VECTOR}
        (self.workdir / "videos").mkdir(parents=True, exist_ok=True)
        self.frames = FrameTableWriter(self.workdir / FRAMES_FILE, self.plan.fps, vector_dtypes)
        self.cameras: dict[str, CameraSink] = {}
        self.widths: dict[str, int] = {}
        self._camera_sources = {
            f.key: f.sources[0] for f in self.plan.features if f.kind is FeatureKind.VIDEO
        }

    def on_frame(self, frame: Frame) -> None:
        for key, image in frame.images.items():
            camera = self.cameras.get(key)
            if camera is None:
                camera = CameraSink(
                    self.workdir / "videos" / f"{key}.mp4",
                    self._camera_sources[key],
                    image,
                    self.plan.fps,
                    self.settings,
                    self.fidelity,
                    self.monitor,
                )
                self.cameras[key] = camera
            camera.write(frame.index, image)
        for key, vec in frame.vectors.items():
            width = self.widths.setdefault(key, vec.shape[0])
            if vec.shape[0] != width:
                raise DecodeError(
                    f"{key!r} has {vec.shape[0]} values at frame {frame.index}, {width} before",
                    t_ns=frame.tick_ns,
                    fix="select a fixed set of dimensions with selector.names.",
                )
        self.monitor.add_vectors(frame.index, frame.vectors)
        self.frames.add(frame.index, self.frame_tasks[frame.index], frame.vectors)

    def close(self) -> dict[str, Any]:
        """Close every writer; returns video clip infos by key."""
        self.frames.close()
        return {key: camera.close() for key, camera in self.cameras.items()}


def convert_episode(request: EpisodeRequest) -> EpisodeSummary:
    """Read one bag, align it to the fps grid, encode videos, and stage the result.

    Raises a :class:`bagport.errors.BagportError` subclass naming the bag, topic
    and time of any problem; on error nothing is left in the staging store.
    """
    plan = parse_contract(request.contract_text, request.contract_name)
    settings = EncoderSettings.from_dict(request.encoder)
    stamp = source_stamp(request.bag_uri)
    reusable = _reusable(request, stamp)
    if reusable is not None:
        return reusable
    clean_dead_scratch()  # a worker on another host cleans after its own killed predecessors
    with open_bag(request.bag_uri, msg_definitions=request.msg_definitions) as whole:
        info = whole.info
        reader, timeline, window = scan_episode(whole, plan, request)
        sources, ticks, alignment = align_sources(plan, timeline, request.bag_uri)
        frame_tasks, task_source = resolve_tasks(
            timeline.tasks, ticks, info.custom_data, request, plan.contract.default_task
        )
        keys = clip_keys(request, stamp, plan.fps, sources, ticks)
        reused = find_reusable_clips(request, keys)  # cameras this contract change does not touch
        workdir = scratch_dir("episode")
        try:
            qa_config = QAConfig.model_validate(request.qa)
            monitor = ValueMonitor(qa_config.values, plan.fps, int(ticks.size))
            fidelity = EpisodeFidelity(qa_config.video, workdir / "fidelity-refs", settings.g or 1)
            sinks = _EpisodeSinks(workdir, plan, settings, frame_tasks, monitor, fidelity)
            try:
                assemble_frames(
                    reader,
                    request.bag_uri,
                    [f for f in plan.features if f.key not in reused],
                    [s for s in sources if s.src.key not in reused],  # a reused camera is not even read
                    ticks,
                    sinks.on_frame,
                    plan.source_name,
                    whole,
                )
            finally:
                clips = sinks.close()
            video_checks, video_plots = fidelity.check(clips, plan.fps)  # before publishing: refs are scratch
            extra_plots = _take_reused(workdir, reused, video_checks, video_plots, monitor)
            write_provenance(workdir / PROVENANCE_FILE, sources, ticks)
            extra = [
                *safety_check(reader, qa_config, int(ticks[0]), int(ticks[-1])),
                *integrity_check(info, qa_config),
                task_check(qa_config, frame_tasks),
                *video_checks,
                *skipped_packet_checks(
                    {
                        t.topic: t.skipped_packets
                        for t in timeline.topics.values()
                        if t.skipped_packets is not None
                    }
                ),
            ]
            qa = assess_episode(
                request.bag_uri, qa_config, timeline, sources, ticks, monitor, extra, plan.fps,
                extra_plots=extra_plots, alignment=alignment,
            )  # fmt: skip
            (workdir / QA_FILE).write_text(json.dumps(qa.to_dict()))
            features = _staged_features(plan, sources, sinks, clips, reused)
            stats: dict[str, Any] = {}
            table = pq.read_table(
                workdir / FRAMES_FILE, columns=[f.key for f in features if f.video_info is None]
            )
            for name in table.column_names:
                values = vector_column(table, name)
                stats[name] = {**stats_to_json(vector_stats(values)), **episode_sketch_fields(values)}
            for key, camera in sinks.cameras.items():
                acc = camera.stats
                stats[key] = {**stats_to_json(acc.result()), "histogram": acc.histogram().tolist()}
            stats.update({key: clip.stats for key, clip in reused.items()})
            (workdir / STATS_FILE).write_text(json.dumps(stats))
            target = episode_dir(request.staging_uri, request.episode_id)
            summary = EpisodeSummary(
                episode_id=request.episode_id,
                dir_uri=target,
                bag_uri=request.bag_uri,
                storage=str(info.storage),
                bag_size_bytes=info.size_bytes,
                bag_fingerprint=bag_fingerprint(info),
                manifest_entry=request.manifest_entry,
                fps=plan.fps,
                frames=int(ticks.size),
                first_tick_ns=int(ticks[0]),
                last_tick_ns=int(ticks[-1]),
                tasks=tuple(dict.fromkeys(frame_tasks)),
                task_source=task_source,
                features=features,
                stamp_sources={f"{s.src.key}@{s.src.topic}": s.stamp_used for s in sources},
                videos={f.key: f"videos/{f.key}.mp4" for f in features if f.video_info is not None},
                metadata=dict(request.metadata),
                window_ns=window,
                segment=request.segment,
                label=request.label,
                note=request.note,
                bagport_version=__version__,
                contract_sha256=request.contract_sha256,
                source_stamp=stamp,
                default_task=request.default_task,
                alignment=alignment,
                qa=qa_brief(qa),
                qa_sha256=request.qa_sha256,
                bag_read={**reader.transfer.to_dict(), "warnings": list(info.warnings)},
                clip_keys=keys,
                reused_clips={key: clip.episode_id for key, clip in reused.items()},
            )
            _publish(workdir, target, summary)
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
    return summary


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
    sources: list[AlignedSource],
    sinks: _EpisodeSinks,
    clips: dict[str, Any],
    reused: dict[str, ReusedClip],
) -> tuple[StagedFeature, ...]:
    out = []
    for feature in plan.features:
        mine = [s for s in sources if s.src.key == feature.key]
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
        names = tuple(n for s in mine for n in (s.extractor.names if s.extractor else ()))
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


def _publish(workdir: Path, target: str, summary: EpisodeSummary) -> None:
    """Move the finished artifact to the staging store; the summary goes last (completion marker)."""
    fs, path = url_to_fs(target)
    if fs.exists(path):
        fs.rm(path, recursive=True)
    fs.makedirs(path, exist_ok=True)
    for item in sorted(workdir.rglob("*")):
        if item.is_file():
            remote = staged_path(path, item.relative_to(workdir).as_posix())
            fs.makedirs(remote.rsplit("/", 1)[0], exist_ok=True)
            fs.put_file(str(item), remote)
    write_json(staged_path(target, EPISODE_SUMMARY), summary.to_dict())
