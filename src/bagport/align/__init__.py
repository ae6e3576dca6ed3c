"""Time alignment: the frame grid and per-stream message selection."""

from __future__ import annotations

from bagport.align.grid import NS_PER_S, grid_ticks_ns, tick_count
from bagport.align.select import STRATEGIES, Selection, hold_fill, select_for_ticks, select_hold

__all__ = [
    "NS_PER_S",
    "STRATEGIES",
    "Selection",
    "grid_ticks_ns",
    "hold_fill",
    "select_for_ticks",
    "select_hold",
    "tick_count",
]
