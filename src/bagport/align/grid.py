"""The fixed frame grid: tick k of an episode is at ``start_ns + floor(k * 1e9 / fps)``.

Integer nanoseconds throughout, so ticks never drift however long the episode.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["NS_PER_S", "grid_drift_ns", "grid_ticks_ns", "reference_ticks_ns", "tick_count"]

NS_PER_S = 1_000_000_000

Int64Array = npt.NDArray[np.int64]


def tick_count(start_ns: int, end_ns: int, fps: int) -> int:
    """Number of ticks ``t_k <= end_ns`` for ``k >= 0``; 0 when ``end_ns < start_ns``."""
    if end_ns < start_ns:
        return 0
    # largest k with floor(k * 1e9 / fps) <= span  <=>  k * 1e9 < (span + 1) * fps
    span = end_ns - start_ns
    return ((span + 1) * fps - 1) // NS_PER_S + 1


def grid_ticks_ns(start_ns: int, end_ns: int, fps: int) -> Int64Array:
    """Absolute tick times in ns from ``start_ns`` up to and including ``end_ns``."""
    count = tick_count(start_ns, end_ns, fps)
    k = np.arange(count, dtype=np.int64)
    return np.int64(start_ns) + (k * NS_PER_S) // fps


def reference_ticks_ns(stamps_ns: Int64Array, start_ns: int, end_ns: int) -> Int64Array:
    """Ticks that follow a reference stream (``clock: <key>``): its distinct stamps in the window, sorted.

    Out-of-order stamps are sorted and duplicated stamps give one tick, so ticks strictly increase.
    """
    inside = stamps_ns[(stamps_ns >= start_ns) & (stamps_ns <= end_ns)]
    return np.unique(inside).astype(np.int64)


def grid_drift_ns(ticks_ns: Int64Array, fps: int) -> Int64Array:
    """How far each tick is from where ``timestamp = frame_index / fps`` puts it (tick 0 as anchor)."""
    if ticks_ns.size == 0:
        return np.zeros(0, dtype=np.int64)
    k = np.arange(ticks_ns.size, dtype=np.int64)
    drift: Int64Array = ticks_ns - (ticks_ns[0] + (k * NS_PER_S) // fps)
    return drift
