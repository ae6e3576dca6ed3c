"""Decide, before streaming, which message feeds every tick of every source, and report how well.

Missing values are handled by each source's ``align.fill`` policy (``fail`` by default), never
silently; the per-source report (alignment error, held / interpolated / filled / dropped frames)
goes into the episode summary, the provenance log and the QA record (:func:`bagport.qa.alignment_checks`).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.align import (
    NS_PER_S,
    Selection,
    grid_drift_ns,
    grid_ticks_ns,
    hold_fill,
    interpolation_span_ns,
    reference_ticks_ns,
    select_for_ticks,
    select_hold,
)
from bagport.contract import ContractPlan, FeatureKind, SourceSpec
from bagport.contract.model import StampSource
from bagport.episode.timeline import Timeline, TopicTimeline
from bagport.errors import AlignmentError

__all__ = ["AlignedSource", "Alignment", "align_sources"]

Int64Array = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class AlignedSource:
    """One contract source with its per-tick message selection (decided before streaming)."""

    src: SourceSpec
    kind: FeatureKind
    timeline: TopicTimeline
    stamp_used: str
    selection: Selection
    filled: BoolArray
    """Ticks whose value comes from ``align.fill`` (held past a gap, or zeros)."""


@dataclass(frozen=True, slots=True)
class Alignment:
    """Which message feeds every tick of every source, the ticks, and how well they line up."""

    sources: tuple[AlignedSource, ...]
    ticks_ns: Int64Array
    report: tuple[dict[str, Any], ...]
    """Per source: stamp, strategy, fill, alignment error (ms), held/interpolated/filled/dropped frames."""

    @property
    def frames(self) -> int:
        return int(self.ticks_ns.size)

    def of(self, keys: Collection[str]) -> tuple[AlignedSource, ...]:
        """The sources of the features ``keys``, in contract order."""
        return tuple(s for s in self.sources if s.src.key in keys)


def _stamp_source(src: SourceSpec, topic: TopicTimeline, uri: str) -> StampSource:
    stamp: StampSource = src.stamp or ("header" if topic.header_ns is not None else "receive")
    if stamp == "header" and topic.header_ns is None:
        raise AlignmentError(
            f"align.stamp is 'header' for {src.key!r} but {src.topic} has no usable header stamps "
            "(type without header, stamps left at zero, or one constant stamp)",
            uri=uri,
            topic=src.topic,
            fix="set 'align: {stamp: receive}' for this entry.",
        )
    if stamp == "publish" and topic.publish_ns is None:
        raise AlignmentError(
            f"align.stamp is 'publish' for {src.key!r} but the bag records no publish time "
            "(only MCAP bags do; ROS 1 and SQLite bags store the receive time alone)",
            uri=uri,
            topic=src.topic,
            fix="set 'align: {stamp: receive}' or 'stamp: header' for this entry.",
        )
    return stamp


_Chosen = tuple[SourceSpec, TopicTimeline, StampSource]


def _window(chosen: list[_Chosen], uri: str) -> tuple[int, int]:
    """Ticks where every source has data at ``tick + offset``: the latest first stamp to the earliest last."""
    firsts = [(int(t.stamps(s).min()) - src.offset_ns, t.topic) for src, t, s in chosen]
    lasts = [(int(t.stamps(s).max()) - src.offset_ns, t.topic) for src, t, s in chosen]
    start_ns, start_topic = max(firsts)
    end_ns, end_topic = min(lasts)
    if end_ns < start_ns:
        ranges = "; ".join(
            f"{t.topic}: {int(t.stamps(s).min())}..{int(t.stamps(s).max())} ns" for _, t, s in chosen
        )
        raise AlignmentError(
            f"the streams never overlap in time ({start_topic} starts after {end_topic} ends): {ranges}",
            uri=uri,
            fix="check the topics, the stamp source (header vs receive) and action_offset_ms in the contract.",
        )
    before, after = _longest_silence(chosen, start_ns, end_ns)
    if end_ns - start_ns > MAX_EPISODE_NS:
        raise _clock_step_error(start_ns, end_ns, before, after, uri)
    if after - before > MAX_SILENCE_NS:
        raise AlignmentError(
            f"no stream has a message for {(after - before) / NS_PER_S:,.0f} s, from {_utc(before)} to {_utc(after)}: "
            "the recording paused or its clock stepped, and every frame across the silence would hold the values "
            "before it",
            uri=uri,
            fix="split the bag at its silences (the contract's 'episodes: {gap_s: 5}', docs/episodes.md), or convert "
            "a part of it with a manifest window (start_ns/end_ns).",
        )
    return start_ns, end_ns


MAX_EPISODE_NS = 24 * 3600 * NS_PER_S
"""An episode longer than a day is a clock that stepped while recording, not a demonstration: refused before
its frame grid (17 billion ticks for a bag whose first messages were logged at time 0) is allocated."""
MAX_SILENCE_NS = 60 * NS_PER_S
"""Every stream silent for longer inside an episode: a recording paused or a clock step, refused before the
frames across it (all holding the values before it) are encoded."""


def _longest_silence(chosen: list[_Chosen], start_ns: int, end_ns: int) -> tuple[int, int]:
    """The two stamps (any stream's) around the longest stretch in ``[start_ns, end_ns]`` with none."""
    stamps = np.unique(np.concatenate([t.stamps(s) - src.offset_ns for src, t, s in chosen]))
    stamps = stamps[(stamps >= start_ns) & (stamps <= end_ns)]
    if stamps.size < 2:
        return start_ns, start_ns
    at = int(np.argmax(np.diff(stamps)))
    return int(stamps[at]), int(stamps[at + 1])


def _utc(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / NS_PER_S, tz=UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _clock_step_error(start_ns: int, end_ns: int, before: int, after: int, uri: str) -> AlignmentError:
    return AlignmentError(
        f"the episode would last {(end_ns - start_ns) / NS_PER_S:,.0f} s ({_utc(start_ns)} to {_utc(end_ns)}), more "
        f"than a day: no stream has a message from {_utc(before)} to {_utc(after)}, so the clock stepped while "
        "recording (messages logged at time 0 by a node on sim time before /clock, or the system clock set)",
        uri=uri,
        fix="convert the part after the step with a manifest window (start_ns/end_ns), or align on header stamps "
        "('align: {stamp: header}') when they are right.",
    )


def _clock_ticks(
    plan: ContractPlan, chosen: list[_Chosen], start_ns: int, end_ns: int, uri: str
) -> tuple[Int64Array, dict[str, Any]]:
    """One tick per message of the ``clock`` stream (its first source), and how far they drift off the grid."""
    src, topic, stamp = next(c for c in chosen if c[0].key == plan.clock)
    ticks = reference_ticks_ns(topic.stamps(stamp), start_ns, end_ns)
    if ticks.size < 2:
        raise AlignmentError(
            f"the clock stream {src.key!r} has {ticks.size} message(s) while every stream has data",
            uri=uri,
            topic=src.topic,
            fix="choose another 'clock' key, or remove it for the fixed grid.",
        )
    rate_hz = NS_PER_S / float(np.median(np.diff(ticks)))
    if abs(rate_hz - plan.fps) > 0.05 * plan.fps:
        raise AlignmentError(
            f"the clock stream {src.key!r} runs at {rate_hz:.2f} Hz (median period) but fps is {plan.fps}: "
            "frames stamped frame_index / fps would run at the wrong speed",
            uri=uri,
            topic=src.topic,
            fix=f"set 'fps: {round(rate_hz)}', or remove 'clock' for the fixed grid.",
        )
    drift_ms = np.abs(grid_drift_ns(ticks, plan.fps)) / 1e6
    clock = {
        "key": src.key,
        "rate_hz": round(rate_hz, 3),
        "drift_ms": {
            "median": float(np.median(drift_ms)),
            "p95": float(np.percentile(drift_ms, 95)),
            "max": float(drift_ms.max()),
        },
    }
    return ticks, clock


def _why_missing(src: SourceSpec, stamps: Int64Array, fps: int) -> str:
    if src.strategy != "interpolate":
        return ""
    span_ms = interpolation_span_ns(stamps, fps, src.tol_ms) / 1e6
    default = "" if src.tol_ms is not None else " (the default: 5 median message intervals or 2 frames)"
    return f": the messages around them are more than {span_ms:g} ms apart{default}, a dropout"


def _missing_error(
    src: SourceSpec, missing: BoolArray, ticks: Int64Array, uri: str, why: str
) -> AlignmentError:
    first = int(ticks[np.flatnonzero(missing)[0]])
    return AlignmentError(
        f"{int(missing.sum())} of {ticks.size} frames have no {src.key!r} message under align.strategy "
        f"{src.strategy!r}{why} (first at t_ns={first}, {(first - ticks[0]) / 1e9:.3f} s into the episode)",
        uri=uri,
        topic=src.topic,
        fix="raise align.tol_ms (for interpolate: the longest silence bridged), use 'strategy: hold', "
        "or choose align.fill (hold, zeros, drop_frame); "
        "bagport never fills missing values silently.",
    )


def _report(
    src: SourceSpec, stamp: StampSource, stamps: Int64Array, sel: Selection, filled: BoolArray,
    targets: Int64Array, fps: int, dropped: int,
) -> dict[str, Any]:  # fmt: skip
    """Alignment error ``|tick + offset - source time|`` and frame counts of one source."""
    valid = sel.lo >= 0
    used = stamps[np.maximum(sel.lo, 0)]
    if sel.hi is not None and sel.weight is not None:
        other = stamps[np.maximum(sel.hi, 0)]
        used = np.where(sel.weight >= 0.5, other, used)
    error_ms = np.abs(targets - used)[valid & ~filled] / 1e6
    period_ns = NS_PER_S // fps
    interpolated = 0 if sel.weight is None else int(((sel.weight > 0) & valid & ~filled).sum())
    return {
        "key": src.key,
        "topic": src.topic,
        "stamp": stamp,
        "strategy": src.strategy,
        "fill": src.fill,
        "offset_ms": src.offset_ns / 1e6,
        "error_ms": {
            "median": float(np.median(error_ms)) if error_ms.size else None,
            "p95": float(np.percentile(error_ms, 95)) if error_ms.size else None,
            "max": float(error_ms.max()) if error_ms.size else None,
        },
        "held_frames": int(((targets - stamps[np.maximum(sel.lo, 0)]) >= period_ns)[valid & ~filled].sum()),
        "interpolated_frames": interpolated,
        "filled_frames": int(filled.sum()),
        "dropped_frames": dropped,
    }


def _select(
    src: SourceSpec, stamps: Int64Array, ticks: Int64Array, fps: int, uri: str
) -> tuple[Selection, BoolArray, BoolArray]:
    """One source's selection per tick, its filled ticks, and the ticks it drops (``drop_frame``)."""
    targets = ticks + src.offset_ns
    sel = select_for_ticks(stamps, targets, strategy=src.strategy, fps=fps, tol_ms=src.tol_ms)
    filled: BoolArray = np.zeros(ticks.size, dtype=np.bool_)
    dropped: BoolArray = np.zeros(ticks.size, dtype=np.bool_)
    missing = sel.missing
    if not missing.any():
        return sel, filled, dropped
    if src.fill == "fail":
        raise _missing_error(src, missing, ticks, uri, _why_missing(src, stamps, fps))
    if src.fill == "hold":
        sel, filled = hold_fill(sel, select_hold(stamps, targets))
        if sel.missing.any():
            raise _missing_error(src, sel.missing, ticks, uri, " and nothing earlier to hold")
    elif src.fill == "zeros":
        filled = missing
    else:  # drop_frame
        dropped = missing
    return sel, filled, dropped


def _ticks(plan: ContractPlan, chosen: list[_Chosen], uri: str) -> tuple[Int64Array, dict[str, Any] | None]:
    """The frame ticks: the fixed grid over the window every stream has data in, or the clock's messages."""
    start_ns, end_ns = _window(chosen, uri)
    if plan.clock is None:
        return grid_ticks_ns(start_ns, end_ns, plan.fps), None
    return _clock_ticks(plan, chosen, start_ns, end_ns, uri)


def align_sources(plan: ContractPlan, timeline: Timeline, uri: str) -> Alignment:
    """Sources with their per-tick selections, the tick times, and the alignment report.

    Each source is sampled at ``tick + offset_ns`` (``action_offset_ms`` on actions).  The ticks
    are the fixed grid from the first moment every stream has data, or, with ``clock: <key>``,
    the messages of that stream (whose report then carries the clock's rate and drift).
    """
    chosen: list[_Chosen] = []
    kinds = []
    for feature in plan.features:
        for src in feature.sources:
            topic = timeline.topics[src.stream]
            chosen.append((src, topic, _stamp_source(src, topic, uri)))
            kinds.append(feature.kind)
    ticks, clock = _ticks(plan, chosen, uri)
    selections = [_select(src, topic.stamps(stamp), ticks, plan.fps, uri) for src, topic, stamp in chosen]
    keep: BoolArray = np.ones(ticks.size, dtype=np.bool_)
    for _, _, dropped in selections:
        keep &= ~dropped
    if not keep.any():
        raise AlignmentError(
            "align.fill 'drop_frame' dropped every frame", uri=uri, fix="check the alignment settings."
        )
    dropped_frames = int((~keep).sum())
    ticks_kept = ticks[keep]
    sources: list[AlignedSource] = []
    report: list[dict[str, Any]] = []
    for (src, topic, stamp), kind, (sel, filled, _) in zip(chosen, kinds, selections, strict=True):
        source = AlignedSource(src, kind, topic, stamp, sel.take(keep), filled[keep])
        sources.append(source)
        entry = _report(
            src, stamp, topic.stamps(stamp), source.selection, source.filled,
            ticks_kept + src.offset_ns, plan.fps, dropped_frames,
        )  # fmt: skip
        if clock is not None and src.key == clock["key"] and not any("clock" in e for e in report):
            entry["clock"] = clock
        report.append(entry)
    return Alignment(tuple(sources), ticks_kept, tuple(report))
