"""``--format robodm``: one Robo-DM trajectory per episode that ``robodm`` loads back equal to the LeRobot
output, with the original timestamps, the task and the episode's provenance."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from bagport.errors import DatasetWriteError
from bagport.formats.robodm import trajectory_class, write_robodm_dataset
from bagport.staging import EpisodeSummary
from tests.lerobot_frames import lerobot_frames

pytestmark = pytest.mark.slow


def test_robodm_loads_every_episode_equal_to_the_lerobot_output(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]]
) -> None:
    root, summaries = staged
    out = tmp_path / "ds.robodm"
    level = logging.getLogger().level
    report = write_robodm_dataset(summaries, str(out), robot_type="bagport_sample_arm", run_record={"run": 1})
    assert logging.getLogger().level == level  # robodm's import did not reconfigure logging
    assert report.root == str(out) and report.frames == sum(s.frames for s in summaries)
    assert sorted(p.name for p in out.iterdir()) == ["episode_0.vla", "episode_1.vla", "meta"]
    info = json.loads((out / "meta/info.json").read_text())
    assert info["format"] == "robodm" and info["features"]["action"]["names"][0] == "position.j1"
    assert (out / "meta/provenance/run.json").is_file()
    trajectory = trajectory_class()
    loaded = [trajectory(str(out / f"episode_{i}.vla"), mode="r").load() for i in range(2)]
    for i, data in enumerate(loaded):
        episode = json.loads(data["episode"][0])
        assert episode["bag_uri"] == summaries[i].bag_uri and episode["fps"] == 30
        assert episode["label"] == summaries[i].label and episode["metadata"] == summaries[i].metadata
        assert data["tick_ns"][0] == summaries[i].first_tick_ns and np.all(np.diff(data["tick_ns"]) > 0)
        # one value per frame in every stream (a stream with fewer would make the muxer buffer the others)
        assert {len(values) for values in data.values()} == {summaries[i].frames}
        assert list(data["episode"][1:]) == [""] * (summaries[i].frames - 1)
    compared = 0
    for frame in lerobot_frames(root / "ds"):
        data, n = loaded[frame.episode_index], frame.frame_index
        assert data["frame_index"][n] == n and data["task"][n] == frame.task
        assert data["timestamp"][n] == np.float32(frame.timestamp)
        for key, vector in frame.vectors.items():
            np.testing.assert_array_equal(data[key][n], vector)
        for key, image in frame.images.items():
            assert data[key][n].dtype == np.uint8
            assert np.abs(data[key][n].astype(int) - image.astype(int)).max() <= 1, (key, n)
        compared += 1
    assert compared == sum(s.frames for s in summaries)


def test_a_clip_shorter_than_its_episode_writes_nothing(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]]
) -> None:
    _, summaries = staged
    broken = EpisodeSummary.from_dict({**summaries[1].to_dict(), "frames": summaries[1].frames + 5})
    with pytest.raises(DatasetWriteError, match=r"holds \d+ frames, the episode"):
        write_robodm_dataset([summaries[0], broken], str(tmp_path / "out"), robot_type="r", run_record={})
    assert not list(tmp_path.iterdir())
