"""meta/stats.json against LeRobot's own stats functions, recomputed from the final dataset: every
frame of the data parquet files, and every video frame as LeRobot's loader decodes it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd
import pytest
from lerobot.datasets.compute_stats import get_feature_stats
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from bagport.dataset import DatasetLimits, write_dataset
from bagport.dataset.validate import video_backend
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.stats import QUANTILES, rank_error
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from bagport.video.settings import EncoderSettings
from tests.helpers import SAMPLE_CONTRACT

pytestmark = pytest.mark.slow

LOSSLESS_RGB = EncoderSettings.from_dict(
    {"codec": "libx264rgb", "pix_fmt": "rgb24", "crf": 0, "g": 2, "preset": "ultrafast"}
)
"""Decoded frames equal the frames the stats were computed from, so they compare to float precision."""
CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48, noise=12.0),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)
VECTORS = ("observation.state", "action", "timestamp", "frame_index", "episode_index", "index", "task_index")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five episodes of different lengths and tasks, over several data and video files."""
    root = tmp_path_factory.mktemp("stats")
    text = SAMPLE_CONTRACT.read_text()
    summaries = []
    for i in range(5):
        bag = root / f"ep{i}"
        spec = EpisodeSpec(duration_s=0.5 + 0.4 * i, seed=i, cameras=CAMERAS, task=f"task {i % 3}")
        write_episode_bag(bag, "mcap", spec)
        request = EpisodeRequest(
            episode_id_for(str(bag), text, LOSSLESS_RGB), str(bag), i, str(root / "staging"), text,
            "sample_robot.yaml", LOSSLESS_RGB,
        )  # fmt: skip
        summaries.append(convert_episode(request))
    out = root / "ds"
    limits = DatasetLimits(chunks_size=2, data_files_size_in_mb=0.002, video_files_size_in_mb=0.05)
    write_dataset(summaries, str(out), robot_type="r", limits=limits)
    assert len(list((out / "data").rglob("*.parquet"))) > 1
    return out


def _recomputed(root: Path) -> tuple[dict[str, npt.NDArray[Any]], dict[str, npt.NDArray[np.uint8]]]:
    """Every vector from the data files; every video frame decoded by LeRobot, as uint8 (N, 3, H, W)."""
    files = sorted((root / "data").rglob("*.parquet"))
    frame = pd.concat([pd.read_parquet(p) for p in files], ignore_index=True)
    vectors = {key: np.stack([np.atleast_1d(v) for v in frame[key]]).astype(np.float64) for key in VECTORS}
    dataset = LeRobotDataset("test/stats", root=root, video_backend=video_backend())
    images: dict[str, list[npt.NDArray[np.uint8]]] = {key: [] for key in dataset.meta.video_keys}
    for index in range(len(dataset)):
        item = dataset[index]
        for key, frames in images.items():
            frames.append(np.rint(item[key].numpy() * 255).astype(np.uint8))
    return vectors, {key: np.stack(frames) for key, frames in images.items()}


def test_merged_stats_equal_lerobot_stats_of_the_final_files(dataset: Path) -> None:
    written = json.loads((dataset / "meta/stats.json").read_text())
    vectors, videos = _recomputed(dataset)
    assert set(written) == set(VECTORS) | set(videos)
    for key, values in vectors.items():
        ours = {stat: np.asarray(v) for stat, v in written[key].items()}
        column = values[:, 0] if values.shape[1] == 1 else values  # scalar columns as LeRobot passes them
        theirs = get_feature_stats(column, axis=0, keepdims=column.ndim == 1)
        assert int(ours["count"][0]) == int(theirs["count"][0]) == len(values), key
        for stat in ("mean", "std", "min", "max"):
            np.testing.assert_allclose(
                ours[stat], theirs[stat], rtol=1e-9, atol=1e-9, err_msg=f"{key}/{stat}"
            )
        eps = rank_error()
        for stat, q in QUANTILES.items():
            # within the sketches' rank error of the exact (inverted-CDF) quantile
            lo = np.quantile(values, max(q - eps, 0.0), axis=0, method="inverted_cdf")
            hi = np.quantile(values, min(q + eps, 1.0), axis=0, method="inverted_cdf")
            assert np.all((lo <= ours[stat]) & (ours[stat] <= hi)), (key, stat)
    for key, frames in videos.items():
        ours = {stat: np.asarray(v) for stat, v in written[key].items()}
        # per channel, as LeRobot does; in float64 (on uint8 LeRobot accumulates in float32, ~1e-3 off)
        theirs = get_feature_stats(frames.astype(np.float64), axis=(0, 2, 3), keepdims=True)
        theirs = {k: v if k == "count" else np.squeeze(v / 255.0, axis=0) for k, v in theirs.items()}
        assert np.asarray(ours["mean"]).shape == (3, 1, 1)
        assert int(ours["count"][0]) == int(theirs["count"][0]) == len(frames), key
        for stat in ("mean", "std", "min", "max"):
            np.testing.assert_allclose(
                ours[stat], theirs[stat], rtol=1e-9, atol=1e-9, err_msg=f"{key}/{stat}"
            )
        pixels = frames.transpose(0, 2, 3, 1).reshape(-1, 3) / 255.0
        for stat, q in QUANTILES.items():
            exact = np.quantile(pixels, q, axis=0, method="inverted_cdf").reshape(3, 1, 1)
            np.testing.assert_allclose(ours[stat], exact, rtol=0, atol=1e-12, err_msg=f"{key}/{stat}")
