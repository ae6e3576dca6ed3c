"""Time alignment: the frame grid and per-stream message selection."""

from __future__ import annotations

from bagport.align.grid import NS_PER_S, grid_drift_ns, grid_ticks_ns, reference_ticks_ns, tick_count
from bagport.align.select import (
    GAP_FACTOR,
    STRATEGIES,
    Selection,
    hold_fill,
    interpolation_span_ns,
    select_for_ticks,
    select_hold,
)
from bagport.align.slerp import QuaternionGroup, blend, quaternion_groups, slerp

__all__ = [
    "GAP_FACTOR",
    "NS_PER_S",
    "STRATEGIES",
    "QuaternionGroup",
    "Selection",
    "blend",
    "grid_drift_ns",
    "grid_ticks_ns",
    "hold_fill",
    "interpolation_span_ns",
    "quaternion_groups",
    "reference_ticks_ns",
    "select_for_ticks",
    "select_hold",
    "slerp",
    "tick_count",
]
