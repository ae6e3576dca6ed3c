"""300 short episodes joined into one video file: ``from_timestamp`` stays exact, so LeRobot decodes
every frame with its default tolerance, and each decoded frame is the one that was staged."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import av
import numpy as np
import numpy.typing as npt
import pandas as pd
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from bagport.dataset import write_dataset
from bagport.dataset.invariants import check_invariants
from bagport.dataset.validate import video_backend
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.qa import QAConfig
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_SETTINGS

pytestmark = pytest.mark.slow

EPISODES = 300
FPS = 30
KEY = "observation.images.front"
CONTRACT = f"""
robot_type: tiny_arm
fps: {FPS}
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [position.j1, position.j2]}}
  - key: {KEY}
    topic: /front/image_raw
    type: sensor_msgs/msg/Image
actions:
  - key: action
    publish: {{topic: /cmd, type: sensor_msgs/msg/JointState}}
    selector: {{names: [position.j1, position.j2]}}
"""


def _clip_frames(summary: EpisodeSummary) -> list[npt.NDArray[np.uint8]]:
    frames: list[npt.NDArray[np.uint8]] = []
    with av.open(summary.file(summary.videos[KEY])) as container:
        frames.extend(
            np.asarray(frame.to_ndarray(format="rgb24"), dtype=np.uint8)
            for frame in container.decode(video=0)
        )
    return frames


@pytest.fixture(scope="module")
def many(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[EpisodeSummary]]:
    """Seven staged episodes of about 3..9 frames (noisy: every frame differs), cycled into 300 episodes."""
    root = tmp_path_factory.mktemp("many")
    camera = CameraSpec("front", "raw", "rgb8", height=16, width=16, noise=30.0)
    staged = []
    for i in range(7):
        bag = root / f"ep{i}"
        spec = EpisodeSpec(
            duration_s=(3 + i) / FPS + 0.02, seed=i, cameras=(camera,), joint_names=("j1", "j2"), task=f"t{i}"
        )
        write_episode_bag(bag, "mcap", spec)
        request = EpisodeRequest(
            episode_id_for(str(bag), CONTRACT, FAST_SETTINGS), str(bag), i, str(root / "staging"), CONTRACT,
            "tiny.yaml", FAST_SETTINGS, qa=QAConfig.model_validate({"video": {"fidelity": False}}),
        )  # fmt: skip
        staged.append(convert_episode(request))
    assert len({s.frames for s in staged}) >= 4, [s.frames for s in staged]  # episodes of unequal length
    summaries = [replace(staged[n % 7], episode_id=f"e{n:03d}", manifest_entry=n) for n in range(EPISODES)]
    out = root / "ds"
    write_dataset(summaries, str(out), robot_type="tiny_arm")
    return out, summaries


def test_300_episodes_share_one_video_file_with_exact_timestamps(
    many: tuple[Path, list[EpisodeSummary]],
) -> None:
    out, summaries = many
    check_invariants(out)
    assert [p.relative_to(out).as_posix() for p in sorted((out / "videos").rglob("*.mp4"))] == [
        f"videos/{KEY}/chunk-000/file-000.mp4"
    ]
    episodes = pd.read_parquet(out / "meta/episodes/chunk-000/file-000.parquet")
    starts = np.cumsum([0] + [s.frames for s in summaries])
    assert episodes[f"videos/{KEY}/from_timestamp"].tolist() == [float(n / FPS) for n in starts[:-1]]
    assert episodes[f"videos/{KEY}/to_timestamp"].tolist() == [float(n / FPS) for n in starts[1:]]
    info = json.loads((out / "meta/info.json").read_text())
    assert (info["total_episodes"], info["total_frames"]) == (EPISODES, starts[-1])


def test_lerobot_decodes_every_frame_of_300_episodes_as_staged(
    many: tuple[Path, list[EpisodeSummary]],
) -> None:
    out, summaries = many
    dataset = LeRobotDataset("test/many", root=out, video_backend=video_backend())  # default tolerance_s
    assert dataset.tolerance_s == pytest.approx(1e-4)
    expected = {s.dir_uri: _clip_frames(s) for s in summaries[:7]}
    index = 0
    for episode_index, summary in enumerate(summaries):
        for frame_index, truth in enumerate(expected[summary.dir_uri]):
            item = dataset[index]  # raises when a frame is not within tolerance of its timestamp
            assert (int(item["episode_index"]), int(item["frame_index"])) == (episode_index, frame_index)
            decoded = np.rint(item[KEY].numpy().transpose(1, 2, 0) * 255).astype(np.uint8)
            np.testing.assert_array_equal(
                decoded, truth, err_msg=f"episode {episode_index} frame {frame_index}"
            )
            index += 1
    assert index == len(dataset)
