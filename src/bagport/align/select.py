"""Which message feeds which tick: pure functions over per-stream stamp arrays.

A stream's stamps are given in log (arrival) order; results index into that order so
the converter can pick messages while streaming.  ``-1`` means no message.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bagport.align.grid import NS_PER_S

__all__ = [
    "GAP_FACTOR",
    "STRATEGIES",
    "Selection",
    "hold_fill",
    "interpolation_span_ns",
    "select_for_ticks",
    "select_hold",
]

Int64Array = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

STRATEGIES = ("hold", "asof", "drop", "nearest", "interpolate")
GAP_FACTOR = 5
"""``interpolate`` without ``tol_ms``: a silence this many median message intervals long is a dropout."""


@dataclass(frozen=True, slots=True)
class Selection:
    """Per tick: the message (``lo``) and, when interpolating, the next one (``hi``) and its share."""

    lo: Int64Array
    hi: Int64Array | None = None
    weight: FloatArray | None = None

    @property
    def missing(self) -> BoolArray:
        return self.lo < 0

    def take(self, keep: BoolArray) -> Selection:
        return Selection(
            self.lo[keep],
            None if self.hi is None else self.hi[keep],
            None if self.weight is None else self.weight[keep],
        )


def _sorted(stamps_ns: Int64Array) -> tuple[Int64Array, Int64Array]:
    order = np.argsort(stamps_ns, kind="stable").astype(np.int64)
    return order, stamps_ns[order]


def select_hold(stamps_ns: Int64Array, ticks_ns: Int64Array) -> Int64Array:
    """Latest message with stamp <= tick (ties: the last logged); -1 before the first.

    Out-of-order stamps are handled: "latest" means the largest stamp, not the last logged.
    """
    if stamps_ns.size == 0:
        return np.full(ticks_ns.shape, -1, dtype=np.int64)
    order, ordered = _sorted(stamps_ns)
    pos = np.searchsorted(ordered, ticks_ns, side="right") - 1
    return np.where(pos >= 0, order[np.maximum(pos, 0)], -1).astype(np.int64)


def _select_next(stamps_ns: Int64Array, ticks_ns: Int64Array) -> Int64Array:
    """Earliest message with stamp >= tick (ties: the first logged); -1 after the last."""
    if stamps_ns.size == 0:
        return np.full(ticks_ns.shape, -1, dtype=np.int64)
    order, ordered = _sorted(stamps_ns)
    pos = np.searchsorted(ordered, ticks_ns, side="left")
    return np.where(pos < ordered.size, order[np.minimum(pos, ordered.size - 1)], -1).astype(np.int64)


def _nearest(stamps_ns: Int64Array, ticks_ns: Int64Array, tol_ns: int) -> Int64Array:
    before = select_hold(stamps_ns, ticks_ns)
    after = _select_next(stamps_ns, ticks_ns)
    gap_before = np.where(before >= 0, ticks_ns - stamps_ns[np.maximum(before, 0)], np.iinfo(np.int64).max)
    gap_after = np.where(after >= 0, stamps_ns[np.maximum(after, 0)] - ticks_ns, np.iinfo(np.int64).max)
    chosen = np.where(gap_before <= gap_after, before, after)
    gap = np.minimum(gap_before, gap_after)
    return np.where(gap <= tol_ns, chosen, -1).astype(np.int64)


def interpolation_span_ns(stamps_ns: Int64Array, fps: int, tol_ms: float | None) -> int:
    """The longest silence ``interpolate`` bridges: ``tol_ms``, else the larger of
    :data:`GAP_FACTOR` times the stream's median message interval and two frame periods.

    A tick inside a longer silence is a dropout, not a trend: it is missing and ``fill`` decides.
    """
    if tol_ms is not None:
        return round(tol_ms * 1_000_000)
    steps = np.diff(np.unique(stamps_ns))
    typical_ns = int(np.median(steps)) if steps.size else 0
    return max(GAP_FACTOR * typical_ns, 2 * NS_PER_S // fps)


def _interpolate(stamps_ns: Int64Array, ticks_ns: Int64Array, max_span_ns: int) -> Selection:
    lo = select_hold(stamps_ns, ticks_ns)
    hi = _select_next(stamps_ns, ticks_ns)
    s_lo = stamps_ns[np.maximum(lo, 0)]
    s_hi = stamps_ns[np.maximum(hi, 0)]
    span = s_hi - s_lo
    inside = (lo >= 0) & (hi >= 0) & (span <= max_span_ns)
    share = (ticks_ns - s_lo).astype(np.float64) / np.where(span > 0, span, 1).astype(np.float64)
    weight = np.where(inside & (span > 0), share, 0.0)
    return Selection(np.where(inside, lo, -1), np.where(inside, hi, -1), weight)


def select_for_ticks(
    stamps_ns: Int64Array, ticks_ns: Int64Array, *, strategy: str, fps: int, tol_ms: float | None
) -> Selection:
    """Apply an alignment strategy; a tick without a valid message gets ``lo = -1``.

    - ``hold``: latest at or before the tick, however old.
    - ``asof``: latest at or before the tick if it is at most ``tol_ms`` old.
    - ``drop``: latest at or before the tick if it arrived in the frame window ``(tick - 1/fps, tick]``.
    - ``nearest``: the closest message within ``tol_ms``, before or after (looks ahead: opt-in).
    - ``interpolate``: linear between the messages around the tick if they are at most
      :func:`interpolation_span_ns` apart (looks ahead: opt-in).
    """
    if strategy == "interpolate":
        return _interpolate(stamps_ns, ticks_ns, interpolation_span_ns(stamps_ns, fps, tol_ms))
    if strategy == "nearest":
        if tol_ms is None:
            raise ValueError("nearest needs tol_ms")
        return Selection(_nearest(stamps_ns, ticks_ns, round(tol_ms * 1_000_000)))
    chosen = select_hold(stamps_ns, ticks_ns)
    if strategy == "hold":
        return Selection(chosen)
    if strategy == "asof":
        if tol_ms is None:
            raise ValueError("asof needs tol_ms")
        max_age_ns = round(tol_ms * 1_000_000)
    elif strategy == "drop":
        max_age_ns = NS_PER_S // fps - 1
    else:
        raise ValueError(f"unknown alignment strategy {strategy!r}")
    valid = chosen >= 0
    age = np.where(valid, ticks_ns - stamps_ns[np.maximum(chosen, 0)], 0)
    return Selection(np.where(valid & (age <= max_age_ns), chosen, -1).astype(np.int64))


def hold_fill(selection: Selection, latest: Int64Array) -> tuple[Selection, BoolArray]:
    """``fill: hold``: a missing tick takes ``latest`` (:func:`select_hold` of the same ticks: the
    newest message at or before it, however old); returns the filled mask.

    Leading missing ticks stay missing: there is nothing earlier to hold.
    """
    filled = (selection.lo < 0) & (latest >= 0)
    new_lo = np.where(filled, latest, selection.lo).astype(np.int64)
    hi = weight = None
    if selection.hi is not None and selection.weight is not None:
        hi = np.where(filled, new_lo, selection.hi).astype(np.int64)
        weight = np.where(filled, 0.0, selection.weight)
    return Selection(new_lo, hi, weight), filled
