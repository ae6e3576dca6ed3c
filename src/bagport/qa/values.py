"""Value checks, fed frame by frame while the episode streams (memory stays flat).

Numeric features: NaN/inf, declared limits, implied velocity above a limit, frozen values.
Cameras: frozen images (a stalled driver, or a dropout held by alignment) and all-dark or
all-bright frames. Images are compared on a sparse pixel grid, which is cheap and exact for
the repeated buffers a frozen stream produces.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import simplejpeg

from bagport.qa.config import Gate, ValuesQA
from bagport.qa.result import CheckResult, judge

__all__ = ["ValueMonitor"]

_GRID_STEP = 8
_TRACE_POINTS = 200
_TRACE_DIMS = 8
_THUMBNAILS = 8
"""Frames per camera kept as small JPEGs for the report's thumbnail strip (evenly spread)."""
_THUMBNAIL_PX = 64


@dataclass(slots=True)
class _Run:
    """Longest run of frames equal to their predecessor."""

    previous: Any = None
    current: int = 0
    longest: int = 0
    longest_end: int = 0

    def update(self, k: int, same: bool) -> None:
        self.current = self.current + 1 if same else 0
        if self.current > self.longest:
            self.longest, self.longest_end = self.current, k


@dataclass(slots=True)
class _VectorState:
    non_finite: int = 0
    first_non_finite: int = -1
    out_of_limits: int = 0
    first_out_of_limits: int = -1
    violations: int = 0
    worst_speed: float = 0.0
    frozen: _Run = field(default_factory=_Run)
    trace: list[list[float]] = field(default_factory=list)


@dataclass(slots=True)
class _ImageState:
    frozen: _Run = field(default_factory=_Run)
    dark_or_bright: int = 0
    first_dark_or_bright: int = -1
    thumbnails: list[dict[str, Any]] = field(default_factory=list)
    means: list[float] = field(default_factory=list)


class ValueMonitor:
    """Accumulates value checks over the frames of one episode."""

    def __init__(self, config: ValuesQA, fps: int, total_frames: int) -> None:
        self._config = config
        self._fps = fps
        self._stride = max(1, -(-total_frames // _TRACE_POINTS))
        self._thumb_every = max(1, -(-total_frames // _THUMBNAILS))
        self._vectors: dict[str, _VectorState] = {}
        self._images: dict[str, _ImageState] = {}
        self.frames = 0

    def add_vectors(self, k: int, vectors: dict[str, npt.NDArray[np.float64]]) -> None:
        for key, vec in vectors.items():
            state = self._vectors.setdefault(key, _VectorState())
            finite = np.isfinite(vec)
            if not finite.all():
                state.non_finite += int((~finite).sum())
                state.first_non_finite = k if state.first_non_finite < 0 else state.first_non_finite
            limits = self._config.limits.get(key)
            if limits is not None:
                outside = int(((vec < limits[0]) | (vec > limits[1])).sum())
                if outside:
                    state.out_of_limits += outside
                    state.first_out_of_limits = (
                        k if state.first_out_of_limits < 0 else state.first_out_of_limits
                    )
            previous = state.frozen.previous
            max_speed = self._config.max_velocity.get(key)
            if previous is not None and max_speed is not None and previous.shape == vec.shape:
                speed = float(np.nanmax(np.abs(vec - previous))) * self._fps if vec.size else 0.0
                state.worst_speed = max(state.worst_speed, speed)
                state.violations += int(speed > max_speed)
            same = (
                previous is not None and previous.shape == vec.shape and bool(np.array_equal(previous, vec))
            )
            state.frozen.update(k, same)
            state.frozen.previous = vec.copy()
            if k % self._stride == 0:
                state.trace.append([round(float(v), 5) for v in vec[:_TRACE_DIMS]])
        self.frames = max(self.frames, k + 1)

    def add_image(self, k: int, key: str, rgb: npt.NDArray[np.uint8]) -> None:
        state = self._images.setdefault(key, _ImageState())
        grid = rgb[::_GRID_STEP, ::_GRID_STEP]
        mean = float(grid.mean())
        if mean < self._config.dark_threshold or mean > self._config.bright_threshold:
            state.dark_or_bright += 1
            state.first_dark_or_bright = k if state.first_dark_or_bright < 0 else state.first_dark_or_bright
        previous = state.frozen.previous
        state.frozen.update(k, previous is not None and bool(np.array_equal(previous, grid)))
        state.frozen.previous = grid.copy()
        if k % self._stride == 0:
            state.means.append(round(mean, 2))
        if k % self._thumb_every == 0:
            state.thumbnails.append({"frame": k, "jpeg": _thumbnail(rgb)})
        self.frames = max(self.frames, k + 1)

    def _at(self, k: int) -> str:
        return f"frame {k} ({k / self._fps:.2f} s)"

    def checks(self) -> list[CheckResult]:
        cfg, out = self._config, []
        for key, s in self._vectors.items():
            where = f", first at {self._at(s.first_non_finite)}" if s.non_finite else ""
            out.append(
                judge(
                    "values.non_finite",
                    key,
                    s.non_finite,
                    cfg.non_finite,
                    f"{s.non_finite} NaN/inf value(s){where}",
                )
            )
            if key in cfg.limits:
                lo, hi = cfg.limits[key]
                where = f", first at {self._at(s.first_out_of_limits)}" if s.out_of_limits else ""
                out.append(judge("values.out_of_limits", key, s.out_of_limits, cfg.out_of_limits,
                                 f"{s.out_of_limits} value(s) outside [{lo:g}, {hi:g}]{where}"))  # fmt: skip
            if key in cfg.max_velocity:
                out.append(judge("values.velocity_violations", key, s.violations, cfg.velocity_violations,
                                 f"{s.violations} frame step(s) faster than {cfg.max_velocity[key]:g}/s "
                                 f"(fastest {s.worst_speed:.3g}/s)"))  # fmt: skip
            out.append(self._frozen_check("values.frozen_state_s", key, s.frozen, cfg.frozen_state_s))
        for key, i in self._images.items():
            out.append(self._frozen_check("values.frozen_image_s", key, i.frozen, cfg.frozen_image_s))
            where = f", first at {self._at(i.first_dark_or_bright)}" if i.dark_or_bright else ""
            out.append(judge("values.dark_or_bright_frames", key, i.dark_or_bright, cfg.dark_or_bright_frames,
                             f"{i.dark_or_bright} frame(s) with mean grey below {cfg.dark_threshold:g} or above "
                             f"{cfg.bright_threshold:g}{where}"))  # fmt: skip
        return out

    def _frozen_check(self, check: str, key: str, run: _Run, gate: Gate) -> CheckResult:
        seconds = run.longest / self._fps
        start = run.longest_end - run.longest
        where = f" from {self._at(start)}" if run.longest else ""
        return judge(check, key, seconds, gate, f"longest run of identical frames {seconds:.2f} s{where}")

    def plots(self) -> dict[str, Any]:
        step_s = self._stride / self._fps
        return {
            "trace_step_s": step_s,
            "vectors": {key: s.trace for key, s in self._vectors.items()},
            "image_means": {key: i.means for key, i in self._images.items()},
            "thumbnails": {key: i.thumbnails for key, i in self._images.items()},
        }


def _thumbnail(image: npt.NDArray[np.uint8]) -> str:
    """A JPEG about :data:`_THUMBNAIL_PX` high, base64 (grey for a depth preview)."""
    step = max(1, image.shape[0] // _THUMBNAIL_PX)
    small = np.ascontiguousarray(image[::step, ::step])
    if small.ndim == 2:
        small = small[:, :, None]
    space = "GRAY" if small.shape[2] == 1 else "RGB"
    return base64.b64encode(simplejpeg.encode_jpeg(small, quality=70, colorspace=space)).decode("ascii")
