"""Decide, before streaming, which message feeds every tick of every source, and report how well.

Missing values are handled by each source's ``align.fill`` policy (``fail`` by default), never
silently; the per-source report (alignment error, held / interpolated / filled / dropped frames)
goes into the episode summary and the provenance log.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.align import NS_PER_S, Selection, grid_ticks_ns, hold_fill, select_for_ticks
from bagport.contract import ContractPlan, SourceSpec
from bagport.contract.model import StampSource
from bagport.episode.assemble import AlignedSource
from bagport.episode.timeline import Timeline, TopicTimeline
from bagport.errors import AlignmentError

__all__ = ["align_sources"]

Int64Array = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


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
    return stamp


def _grid(chosen: list[tuple[SourceSpec, TopicTimeline, StampSource]], fps: int, uri: str) -> Int64Array:
    firsts = [(int(t.stamps(s).min()), t.topic) for _, t, s in chosen]
    lasts = [(int(t.stamps(s).max()), t.topic) for _, t, s in chosen]
    start_ns, start_topic = max(firsts)
    end_ns, end_topic = min(lasts)
    if end_ns < start_ns:
        ranges = "; ".join(
            f"{t.topic}: {int(t.stamps(s).min())}..{int(t.stamps(s).max())} ns" for _, t, s in chosen
        )
        raise AlignmentError(
            f"the streams never overlap in time ({start_topic} starts after {end_topic} ends): {ranges}",
            uri=uri,
            fix="check the topics and the stamp source (header vs receive) in the contract.",
        )
    return grid_ticks_ns(start_ns, end_ns, fps)


def _missing_error(
    src: SourceSpec, missing: BoolArray, ticks: Int64Array, uri: str, why: str
) -> AlignmentError:
    first = int(ticks[np.flatnonzero(missing)[0]])
    return AlignmentError(
        f"{int(missing.sum())} of {ticks.size} frames have no {src.key!r} message under align.strategy "
        f"{src.strategy!r}{why} (first at t_ns={first}, {(first - ticks[0]) / 1e9:.3f} s into the episode)",
        uri=uri,
        topic=src.topic,
        fix="raise align.tol_ms, use 'strategy: hold', or choose align.fill (hold, zeros, drop_frame); "
        "bagport never fills missing values silently.",
    )


def _report(
    src: SourceSpec, stamp: StampSource, stamps: Int64Array, sel: Selection, filled: BoolArray,
    ticks: Int64Array, fps: int, dropped: int,
) -> dict[str, Any]:  # fmt: skip
    valid = sel.lo >= 0
    used = stamps[np.maximum(sel.lo, 0)]
    if sel.hi is not None and sel.weight is not None:
        other = stamps[np.maximum(sel.hi, 0)]
        used = np.where(sel.weight >= 0.5, other, used)
    error_ms = np.abs(ticks - used)[valid & ~filled] / 1e6
    period_ns = NS_PER_S // fps
    interpolated = 0 if sel.weight is None else int(((sel.weight > 0) & valid & ~filled).sum())
    return {
        "key": src.key,
        "topic": src.topic,
        "stamp": stamp,
        "strategy": src.strategy,
        "fill": src.fill,
        "error_ms": {
            "median": float(np.median(error_ms)) if error_ms.size else None,
            "p95": float(np.percentile(error_ms, 95)) if error_ms.size else None,
            "max": float(error_ms.max()) if error_ms.size else None,
        },
        "held_frames": int(((ticks - stamps[np.maximum(sel.lo, 0)]) >= period_ns)[valid].sum()),
        "interpolated_frames": interpolated,
        "filled_frames": int(filled.sum()),
        "dropped_frames": dropped,
    }


def align_sources(
    plan: ContractPlan, timeline: Timeline, uri: str
) -> tuple[list[AlignedSource], Int64Array, list[dict[str, Any]]]:
    """Sources with their per-tick selections, the tick times, and the alignment report."""
    chosen = []
    kinds = []
    for feature in plan.features:
        for src in feature.sources:
            topic = timeline.topics[src.stream]
            chosen.append((src, topic, _stamp_source(src, topic, uri)))
            kinds.append(feature.kind)
    ticks = _grid(chosen, plan.fps, uri)
    selections: list[tuple[Selection, BoolArray]] = []
    keep: BoolArray = np.ones(ticks.size, dtype=np.bool_)
    for src, topic, stamp in chosen:
        sel = select_for_ticks(
            topic.stamps(stamp), ticks, strategy=src.strategy, fps=plan.fps, tol_ms=src.tol_ms
        )
        filled: BoolArray = np.zeros(ticks.size, dtype=np.bool_)
        missing = sel.missing
        if missing.any():
            if src.fill == "fail":
                raise _missing_error(src, missing, ticks, uri, "")
            if src.fill == "hold":
                sel, filled = hold_fill(sel)
                if sel.missing.any():
                    raise _missing_error(src, sel.missing, ticks, uri, " and nothing earlier to hold")
            elif src.fill == "zeros":
                filled = missing
            else:  # drop_frame
                keep &= ~missing
        selections.append((sel, filled))
    if not keep.any():
        raise AlignmentError(
            "align.fill 'drop_frame' dropped every frame", uri=uri, fix="check the alignment settings."
        )
    dropped = int((~keep).sum())
    ticks_kept = ticks[keep]
    sources: list[AlignedSource] = []
    report: list[dict[str, Any]] = []
    for (src, topic, stamp), kind, (sel, filled) in zip(chosen, kinds, selections, strict=True):
        kept, kept_filled = sel.take(keep), filled[keep]
        sources.append(AlignedSource(src, kind, topic, stamp, kept, kept_filled))
        report.append(
            _report(src, stamp, topic.stamps(stamp), kept, kept_filled, ticks_kept, plan.fps, dropped)
        )
    return sources, ticks_kept, report
