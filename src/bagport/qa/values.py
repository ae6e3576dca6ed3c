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

__all__ = ["ValueMonitor", "image_grid"]

_GRID_STEP = 8
"""The image checks' pixel grid: one pixel in 8 each way (:func:`image_grid`)."""
_TRACE_POINTS = 200
_TRACE_DIMS = 8
_THUMBNAILS = 8
"""Frames per camera kept as small JPEGs for the report's thumbnail strip (evenly spread)."""
_THUMBNAIL_PX = 64
_BATCH = 64
"""Frames checked together (per feature): numpy over a batch; held: 64 vectors, or 64 of a camera's sparse grids
(1 MB at 640x480)."""


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
class _Pending:
    """Frames not checked yet (copies, all of one shape and dtype) and their indices."""

    rows: list[npt.NDArray[Any]] = field(default_factory=list)
    ks: list[int] = field(default_factory=list)

    def fits(self, values: npt.NDArray[Any]) -> bool:
        return not self.rows or (values.shape == self.rows[0].shape and values.dtype == self.rows[0].dtype)

    def take(self) -> tuple[npt.NDArray[Any], list[int], npt.NDArray[Any]]:
        """The pending rows flattened and stacked (``frames x values``), their frame indices and the last
        row as it came (the next batch's predecessor); empties the buffer."""
        block, ks, last = np.stack(self.rows).reshape(len(self.rows), -1), self.ks, self.rows[-1]
        self.rows, self.ks = [], []
        return block, ks, last


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
    pending: _Pending = field(default_factory=_Pending)


@dataclass(slots=True)
class _ImageState:
    frozen: _Run = field(default_factory=_Run)
    dark_or_bright: int = 0
    first_dark_or_bright: int = -1
    thumbnails: list[dict[str, Any]] = field(default_factory=list)
    means: list[float] = field(default_factory=list)
    pending: _Pending = field(default_factory=_Pending)


def _same_as_previous(
    block: npt.NDArray[Any], last: npt.NDArray[Any], previous: npt.NDArray[Any] | None
) -> npt.NDArray[np.bool_]:
    """Per row of ``block``: equal to the row before it; the first row to ``previous`` (the frame before
    the batch, as it came) if that has the batch's shape (``last``: the batch's last frame as it came)."""
    same = np.zeros(len(block), np.bool_)
    same[1:] = (block[1:] == block[:-1]).all(axis=1)
    if previous is not None and previous.shape == last.shape:
        same[0] = bool((previous.reshape(-1) == block[0]).all())
    return same


def image_grid(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """The pixels the image checks look at: one in :data:`_GRID_STEP` each way, closer on a frame under
    64 px a side so the grid keeps at least 8 pixels a side (a 2x2 frame: every pixel; with a step of 8 it
    was its first pixel alone, whose value decided "mean grey")."""
    step = min(_GRID_STEP, max(1, min(rgb.shape[0], rgb.shape[1]) // _GRID_STEP))
    return rgb[::step, ::step]


class ValueMonitor:
    """Accumulates value checks over the frames of one episode.

    Frames are checked in batches of :data:`_BATCH` (numpy over a batch instead of a dozen small calls
    per frame: a 2 s episode's checks cost 10 ms before); :meth:`checks` and :meth:`plots` check the
    frames still pending first. Every result is the frame-by-frame one (same counts, first frames, runs).
    """

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
            state = self._vectors.get(key)
            if state is None:
                state = self._vectors[key] = _VectorState()
            if not state.pending.fits(vec):
                self._check_vectors(key, state)
            state.pending.rows.append(vec.copy())
            state.pending.ks.append(k)
            if k % self._stride == 0:
                state.trace.append([round(float(v), 5) for v in vec[:_TRACE_DIMS]])
            if len(state.pending.ks) >= _BATCH:
                self._check_vectors(key, state)
        self.frames = max(self.frames, k + 1)

    def _check_vectors(self, key: str, state: _VectorState) -> None:
        block, ks, last = state.pending.take()
        finite = np.isfinite(block)
        bad = (~finite).sum(axis=1)
        if bad.any():
            state.non_finite += int(bad.sum())
            if state.first_non_finite < 0:
                state.first_non_finite = ks[int(np.argmax(bad > 0))]
        limits = self._config.limits.get(key)
        if limits is not None:
            outside = ((block < limits[0]) | (block > limits[1])).sum(axis=1)
            if outside.any():
                state.out_of_limits += int(outside.sum())
                if state.first_out_of_limits < 0:
                    state.first_out_of_limits = ks[int(np.argmax(outside > 0))]
        previous = state.frozen.previous
        max_speed = self._config.max_velocity.get(key)
        if max_speed is not None:
            follows = previous is not None and previous.shape == last.shape
            self._check_speeds(state, block, previous.reshape(-1) if follows else None, max_speed)
        for k, same in zip(ks, _same_as_previous(block, last, previous).tolist(), strict=True):
            state.frozen.update(k, same)
        state.frozen.previous = last

    def _check_speeds(
        self,
        state: _VectorState,
        block: npt.NDArray[Any],
        previous: npt.NDArray[Any] | None,
        max_speed: float,
    ) -> None:
        """Each frame's largest change from the frame before, per second (NaN-free values only);
        ``previous``: the frame before the batch, flattened, when it has the batch's shape."""
        before = block[:-1]
        if previous is not None:
            before = np.concatenate([previous[None], before])
        after = block[len(block) - len(before) :]
        if not len(after):
            return
        if block.shape[1]:
            # the values of nanmax, without its warning for a frame whose values are all NaN
            speeds = np.fmax.reduce(np.abs(after - before), axis=1).astype(np.float64) * self._fps
        else:
            speeds = np.zeros(len(after))
        measured = speeds[~np.isnan(speeds)]
        if measured.size:
            state.worst_speed = max(state.worst_speed, float(measured.max()))
        state.violations += int((speeds > max_speed).sum())

    def add_image(self, k: int, key: str, rgb: npt.NDArray[np.uint8]) -> None:
        state = self._images.get(key)
        if state is None:
            state = self._images[key] = _ImageState()
        grid = image_grid(rgb)
        if not state.pending.fits(grid):
            self._check_images(state)
        state.pending.rows.append(grid.copy())
        state.pending.ks.append(k)
        if k % self._thumb_every == 0:
            state.thumbnails.append({"frame": k, "jpeg": _thumbnail(rgb)})
        if len(state.pending.ks) >= _BATCH:
            self._check_images(state)
        self.frames = max(self.frames, k + 1)

    def _check_images(self, state: _ImageState) -> None:
        block, ks, last = state.pending.take()
        means = block.mean(axis=1)  # uint8 grids: whole-number sums, so each exactly its frame's mean
        odd = (means < self._config.dark_threshold) | (means > self._config.bright_threshold)
        if odd.any():
            state.dark_or_bright += int(odd.sum())
            if state.first_dark_or_bright < 0:
                state.first_dark_or_bright = ks[int(np.argmax(odd))]
        for k, same in zip(ks, _same_as_previous(block, last, state.frozen.previous).tolist(), strict=True):
            state.frozen.update(k, same)
        state.frozen.previous = last
        state.means += [
            round(float(m), 2) for k, m in zip(ks, means.tolist(), strict=True) if k % self._stride == 0
        ]

    def _check_pending(self) -> None:
        for key, vectors in self._vectors.items():
            if vectors.pending.ks:
                self._check_vectors(key, vectors)
        for images in self._images.values():
            if images.pending.ks:
                self._check_images(images)

    def _at(self, k: int) -> str:
        return f"frame {k} ({k / self._fps:.2f} s)"

    def checks(self) -> list[CheckResult]:
        self._check_pending()
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
        self._check_pending()
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
