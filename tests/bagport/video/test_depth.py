"""Depth video: LeRobot's quantisation formulas, the lossless clip, its exact fidelity check, stats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from bagport.stats import ImageStatsAccumulator, merge_histograms
from bagport.video import StreamingEncoder
from bagport.video.depth import DEPTH_ENCODER, DEPTH_QMAX, DepthQuantizer, histogram_levels
from bagport.video.depth_fidelity import DepthFidelityRecorder, compare_depth_clip

QUANTIZERS = [
    pytest.param(DepthQuantizer(), id="lerobot-default"),
    pytest.param(DepthQuantizer(depth_min_m=0.2, depth_max_m=1.5), id="near-range"),
    pytest.param(DepthQuantizer(use_log=False), id="linear"),
]


def _depth(seed: int, shape: tuple[int, int] = (30, 40), high: float = 12.0) -> npt.NDArray[np.float32]:
    return np.random.default_rng(seed).uniform(0.001, high, shape).astype(np.float32)


@pytest.mark.parametrize("quantizer", QUANTIZERS)
def test_codes_and_levels_are_lerobots(quantizer: DepthQuantizer) -> None:
    depth_utils = pytest.importorskip("lerobot.datasets.depth_utils")
    depth = _depth(0)
    params = {
        "depth_min": quantizer.depth_min_m,
        "depth_max": quantizer.depth_max_m,
        "shift": quantizer.shift_m,
        "use_log": quantizer.use_log,
    }
    theirs = depth_utils.quantize_depth(depth, **params, video_backend=None, input_unit="m")
    np.testing.assert_array_equal(quantizer.codes(depth), theirs)
    codes = np.arange(DEPTH_QMAX + 1, dtype=np.uint16).reshape(1, 1, -1)
    import torch  # noqa: PLC0415 - lerobot's loader dequantises torch tensors

    loaded = depth_utils.dequantize_depth(torch.from_numpy(codes.astype(np.int32)), **params, output_unit="m")
    # float32 maths in both, the order of operations differs: a few micrometres at most (a code is >1 mm)
    np.testing.assert_allclose(quantizer.levels(), loaded.numpy().ravel(), rtol=1e-6, atol=5e-6)


@pytest.mark.parametrize("quantizer", QUANTIZERS)
def test_round_trip_error_is_within_half_a_code(quantizer: DepthQuantizer) -> None:
    depth = _depth(1, high=quantizer.depth_max_m)
    depth = np.maximum(depth, np.float32(quantizer.depth_min_m))
    back = quantizer.levels()[quantizer.codes(depth)]
    bound = np.array([quantizer.step_m(float(d)) for d in depth.ravel()]).reshape(depth.shape) / 2
    assert (np.abs(back - depth) <= bound * 1.001 + 1e-6).all()


def test_invalid_depth_is_code_zero_and_far_depth_is_the_top_code() -> None:
    quantizer = DepthQuantizer()
    codes = quantizer.codes(np.array([[np.nan, np.inf, -np.inf, 0.0, -2.0, 50.0, 0.005]], np.float32))
    np.testing.assert_array_equal(codes, [[0, 0, 0, 0, 0, DEPTH_QMAX, 0]])
    assert quantizer.levels()[0] == pytest.approx(0.01) and quantizer.levels()[-1] == pytest.approx(10.0)


def test_info_marks_the_feature_and_levels_come_back_from_it() -> None:
    quantizer = DepthQuantizer(depth_min_m=0.1, depth_max_m=4.0)
    info = {**DEPTH_ENCODER.to_info(), **quantizer.to_info()}
    assert info["is_depth_map"] is True and info["depth_unit"] == "m"
    assert info["video.extra_options"] == {"x265-params": "lossless=1"}
    levels = histogram_levels(info)
    assert levels is not None
    np.testing.assert_array_equal(levels, quantizer.levels())
    assert histogram_levels({"is_depth_map": False}) is None


def _encode(path: Path, frames: list[npt.NDArray[np.uint16]]) -> None:
    height, width = frames[0].shape
    with StreamingEncoder(path, fps=30, width=width, height=height, settings=DEPTH_ENCODER) as encoder:
        for codes in frames:
            encoder.write(codes)


def test_depth_clip_is_lossless_and_its_fidelity_check_is_exact(tmp_path: Path) -> None:
    quantizer = DepthQuantizer()
    frames = [quantizer.codes(_depth(seed, (24, 34))) for seed in range(7)]  # odd sizes on purpose
    _encode(tmp_path / "d.mp4", frames)
    good = DepthFidelityRecorder(tmp_path / "good.crc")
    for codes in frames:
        good.record(codes)
    result = compare_depth_clip(tmp_path / "d.mp4", good, fps=30)
    assert (result.frames_decoded, result.frames_expected, result.damaged_frames) == (7, 7, 0)
    assert result.pts_ok and result.decode_error is None and result.sampled_frames == 7
    # a clip that does not hold what was encoded is caught, frame by frame
    bad = DepthFidelityRecorder(tmp_path / "bad.crc")
    for n, codes in enumerate(frames):
        bad.record(codes if n != 4 else np.roll(codes, 1))
    bad.record(frames[0])
    result = compare_depth_clip(tmp_path / "d.mp4", bad, fps=30)
    assert result.damaged_frame_indices == (4,) and not result.frames_ok


def test_lerobot_decodes_the_clip_to_the_same_codes(tmp_path: Path) -> None:
    video_utils = pytest.importorskip("lerobot.datasets.video_utils")
    quantizer = DepthQuantizer()
    frames = [quantizer.codes(_depth(seed, (16, 20))) for seed in range(4)]
    _encode(tmp_path / "d.mp4", frames)
    decoded = video_utils.decode_video_frames_pyav(
        tmp_path / "d.mp4", [n / 30 for n in range(4)], 1e-4, is_depth=True
    )
    for n, codes in enumerate(frames):
        np.testing.assert_array_equal(decoded[n, 0].numpy(), codes)


def test_depth_stats_are_in_metres_of_the_loaded_depth_and_merge_exactly() -> None:
    quantizer = DepthQuantizer()
    levels = quantizer.levels()
    episodes = [[quantizer.codes(_depth(10 * e + n, (20, 30), high=8.0)) for n in range(5)] for e in range(2)]
    accs = []
    for frames in episodes:
        acc = ImageStatsAccumulator(bins=DEPTH_QMAX + 1, levels=levels)
        for codes in frames:
            acc.update(codes)
        accs.append(acc)
        stats = acc.result()
        values = levels[np.stack(frames)]
        assert stats["mean"].shape == (1, 1, 1)
        assert stats["mean"].item() == pytest.approx(values.mean(), rel=1e-9)
        assert stats["std"].item() == pytest.approx(values.std(), rel=1e-6)
        assert (stats["min"].item(), stats["max"].item()) == (values.min(), values.max())
        for key, q in (("q01", 0.01), ("q50", 0.5), ("q99", 0.99)):  # exact: the histogram holds every pixel
            assert stats[key].item() == np.quantile(values, q, method="inverted_cdf")
        assert stats["count"].tolist() == [5]
    merged = merge_histograms([a.histogram() for a in accs], [5, 5], levels)
    everything = levels[np.stack([c for frames in episodes for c in frames])]
    assert merged["mean"].item() == pytest.approx(everything.mean(), rel=1e-9)
    assert merged["count"].tolist() == [10]
