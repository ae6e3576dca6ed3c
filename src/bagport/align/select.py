"""Which message feeds which tick: pure functions over per-stream stamp arrays.

A stream's stamps are given in log (arrival) order; the result indexes into that
order so the converter can pick the message while streaming.  ``-1`` = no message.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bagport.align.grid import NS_PER_S

__all__ = ["select_for_ticks", "select_hold"]

Int64Array = npt.NDArray[np.int64]


def select_hold(stamps_ns: Int64Array, ticks_ns: Int64Array) -> Int64Array:
    """Latest message with stamp <= tick (ties: the last logged); -1 before the first.

    Out-of-order stamps are handled: "latest" means the largest stamp, not the last logged.
    """
    if stamps_ns.size == 0:
        return np.full(ticks_ns.shape, -1, dtype=np.int64)
    order = np.argsort(stamps_ns, kind="stable")
    pos = np.searchsorted(stamps_ns[order], ticks_ns, side="right") - 1
    return np.where(pos >= 0, order[np.maximum(pos, 0)], -1).astype(np.int64)


def select_for_ticks(
    stamps_ns: Int64Array, ticks_ns: Int64Array, *, strategy: str, fps: int, tol_ms: float | None
) -> Int64Array:
    """Apply an alignment strategy; a tick without a valid message gets -1.

    - ``hold``: latest at or before the tick, however old.
    - ``asof``: latest at or before the tick if it is at most ``tol_ms`` old.
    - ``drop``: latest at or before the tick if it arrived within the frame window
      ``(tick - 1/fps, tick]``.
    """
    chosen = select_hold(stamps_ns, ticks_ns)
    if strategy == "hold":
        return chosen
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
    return np.where(valid & (age <= max_age_ns), chosen, -1).astype(np.int64)
