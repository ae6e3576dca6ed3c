"""Recording faults to inject into synthetic bags, so each QA check has a bag built to trip it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["Faults", "Window"]

NS = 1_000_000_000
Int64 = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Window:
    """``duration_s`` seconds from ``start_s`` after the episode start (optionally on one camera)."""

    start_s: float
    duration_s: float
    camera: str = ""

    def contains(self, t_ns: int, episode_start_ns: int) -> bool:
        t_s = (t_ns - episode_start_ns) / NS
        return self.start_s <= t_s < self.start_s + self.duration_s


@dataclass(frozen=True, slots=True)
class Faults:
    camera_dropout: Window | None = None
    """No messages from ``camera`` inside the window (a cable glitch)."""
    black_frames: Window | None = None
    """``camera`` publishes all-black images inside the window."""
    frozen_camera: Window | None = None
    """``camera`` repeats the image from the window's start (a stalled driver)."""
    joint_nan_at_s: float | None = None
    """Joint positions are NaN for 50 ms from this time (a driver glitch)."""
    frozen_joints: Window | None = None
    """Joint positions stay at their value from the window's start."""
    joint_spike: tuple[float, float] | None = None
    """``(at_s, rad)``: positions jump by ``rad`` for 100 ms (a kinematic violation)."""
    joint_header_ahead_ns: int = 0
    """Joint header stamps this far ahead of the true capture time (another machine's clock)."""
    joint_out_of_order: int = 0
    """Pairs of consecutive joint messages whose header stamps are swapped."""
    joint_duplicate_stamps: int = 0
    """Joint messages that repeat the previous message's header stamp."""
    joint_clock_jump_s: float = 0.0
    """From mid-episode, joint header stamps jump forward by this much."""
    estop_at_s: float | None = None
    """``/estop`` (std_msgs/Bool at 10 Hz) is true for 0.5 s from this time."""

    ESTOP_TOPIC = "/estop"

    def joint_header_ns(self, stamps_ns: Int64) -> Int64:
        """The header stamps the joint messages carry, given their true capture times."""
        header = stamps_ns + self.joint_header_ahead_ns
        count = header.size
        if self.joint_clock_jump_s:
            header[count // 2 :] += round(self.joint_clock_jump_s * NS)
        for i in range(self.joint_out_of_order):
            k = (i + 1) * count // (self.joint_out_of_order + 2)
            header[k], header[k + 1] = header[k + 1], header[k]
        for i in range(self.joint_duplicate_stamps):
            k = (i + 1) * count // (self.joint_duplicate_stamps + 2) + 3
            header[k + 1] = header[k]
        return header
