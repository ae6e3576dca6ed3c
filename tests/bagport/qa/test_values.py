"""The value checks, batched, give exactly what checking frame by frame gave (counts, first frames, runs,
traces), for streams with NaNs, limits, speeds, frozen runs, dark frames and a change of shape."""

from __future__ import annotations

import json
import warnings
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from bagport.qa import values
from bagport.qa.config import ValuesQA
from bagport.qa.values import ValueMonitor


class FrameByFrame(ValueMonitor):
    """The monitor as it checked each frame when it came (before batching): the oracle."""

    def add_vectors(self, k: int, vectors: dict[str, npt.NDArray[np.float64]]) -> None:
        for key, vec in vectors.items():
            state = self._vectors.setdefault(key, values._VectorState())
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
                with warnings.catch_warnings(action="ignore", category=RuntimeWarning):  # all NaN
                    speed = float(np.nanmax(np.abs(vec - previous))) * self._fps if vec.size else 0.0
                state.worst_speed = max(state.worst_speed, speed)
                state.violations += int(speed > max_speed)
            same = (
                previous is not None and previous.shape == vec.shape and bool(np.array_equal(previous, vec))
            )
            state.frozen.update(k, same)
            state.frozen.previous = vec.copy()
            if k % self._stride == 0:
                state.trace.append([round(float(v), 5) for v in vec[: values._TRACE_DIMS]])
        self.frames = max(self.frames, k + 1)

    def add_image(self, k: int, key: str, rgb: npt.NDArray[np.uint8]) -> None:
        state = self._images.setdefault(key, values._ImageState())
        grid = values.image_grid(rgb)
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
            state.thumbnails.append({"frame": k, "jpeg": values._thumbnail(rgb)})
        self.frames = max(self.frames, k + 1)

    def _check_pending(self) -> None:
        pass


def _stream(rng: np.random.Generator, frames: int) -> list[tuple[dict[str, Any], npt.NDArray[np.uint8]]]:
    """Frames of two vectors and a camera: random walks with held stretches, NaNs and infs, outliers,
    dark and bright frames, a frozen camera run, and the state's width changing once."""
    out = []
    state, action = rng.normal(size=6), rng.normal(size=4).astype(np.float32)
    image = rng.integers(0, 256, (40, 56, 3), np.uint8)
    for k in range(frames):
        held = 50 <= k < 90  # the longest frozen run, across the first batch's end
        if not held and rng.random() > 0.3:  # else held: a frozen frame
            state = state + rng.normal(scale=rng.choice([0.01, 0.5]), size=state.shape)
            action = (action + rng.normal(scale=0.05, size=4)).astype(np.float32)
        if k == frames * 3 // 4:
            state = rng.normal(size=8)  # a new width: no speed or frozen comparison across it
        vec = state.copy()
        if not held and rng.random() < 0.05:
            vec[rng.integers(len(vec))] = rng.choice([np.nan, np.inf, -np.inf])
        if not held and rng.random() < 0.05:
            vec[:] = np.nan
        if not held and rng.random() > 0.2:  # else the same image again
            image = rng.integers(0, 256, (40, 56, 3), np.uint8)
            if rng.random() < 0.1:
                image = np.full_like(image, rng.choice([0, 3, 250, 255]))
        out.append(({"observation.state": vec, "action": action.copy()}, image))
    return out


@pytest.mark.parametrize(("seed", "frames"), [(0, 1), (1, 7), (2, 64), (3, 65), (4, 150), (5, 333)])
def test_batched_checks_are_the_frame_by_frame_ones(seed: int, frames: int) -> None:
    config = ValuesQA.model_validate(
        {
            "limits": {"observation.state": [-1.5, 1.5], "action": [-0.5, 0.5]},
            "max_velocity": {"observation.state": 20.0, "action": 3.0},
        }
    )
    batched, oracle = ValueMonitor(config, 30, frames), FrameByFrame(config, 30, frames)
    for k, (vectors, image) in enumerate(_stream(np.random.default_rng(seed), frames)):
        for monitor in (batched, oracle):
            monitor.add_vectors(k, vectors)
            monitor.add_image(k, "observation.images.front", image)
    assert batched.checks() == oracle.checks()
    assert json.dumps(batched.plots()) == json.dumps(oracle.plots())  # NaN in traces: by their text
    assert batched.frames == oracle.frames == frames
    assert batched.checks() == oracle.checks()  # asked twice: nothing pending is checked twice


@pytest.mark.parametrize(
    ("shape", "step"), [((480, 640, 3), 8), ((96, 128, 3), 8), ((40, 56, 3), 5), ((2, 2, 3), 1)]
)
def test_the_image_grid_keeps_at_least_8_pixels_a_side(shape: tuple[int, int, int], step: int) -> None:
    rgb = np.arange(np.prod(shape), dtype=np.uint64).reshape(shape).astype(np.uint8)
    assert np.array_equal(values.image_grid(rgb), rgb[::step, ::step])


def test_a_tiny_mid_grey_frame_is_not_dark() -> None:
    """A 2x2 frame [0, 128; 128, 255] has mean grey 127.75: it was judged by its first pixel (0), dark."""
    monitor = ValueMonitor(ValuesQA(), fps=1, total_frames=3)
    frame = np.repeat(np.array([[0, 128], [128, 255]], np.uint8)[:, :, None], 3, axis=2)
    for k in range(3):
        monitor.add_image(k, "observation.images.cam", frame)
    dark = [c for c in monitor.checks() if c.check == "values.dark_or_bright_frames"]
    assert [c.value for c in dark] == [0]
