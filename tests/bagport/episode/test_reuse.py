"""A new contract reuses what it does not touch: a changed state selector re-reads the joints but
neither decodes nor encodes the cameras again; a changed camera setting re-encodes that camera only."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

import bagport.episode.assemble
import bagport.episode.sinks
from bagport.dataset import write_dataset
from bagport.dataset.validate import validate_dataset
from bagport.episode import EpisodeRequest, convert_episode
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import SAMPLE_CONTRACT, episode_request

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)
FEWER_JOINTS = SAMPLE_CONTRACT.read_text().replace(
    "names: [position.j1, position.j2, position.j3, position.j4, position.j5, position.j6]\n    align",
    "names: [position.j1, position.j3]\n    align",
    1,  # observation.state only; the action keeps its six joints
)
FRONT_RESIZED = SAMPLE_CONTRACT.read_text().replace(
    "type: sensor_msgs/msg/Image\n", "type: sensor_msgs/msg/Image\n    image: {resize: [16, 24]}\n", 1
)


def _request(bag: Path, staging: Path, text: str) -> EpisodeRequest:
    return episode_request(bag, staging, text)


def test_a_changed_state_selector_reuses_both_camera_clips(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag, staging = tmp_path / "ep", tmp_path / "staging"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=1.0, cameras=CAMERAS))
    assert SAMPLE_CONTRACT.read_text() != FEWER_JOINTS
    first = convert_episode(_request(bag, staging, SAMPLE_CONTRACT.read_text()))
    assert first.reused_clips == {}
    assert set(first.clip_keys) == {"observation.images.front", "observation.images.wrist"}

    decoded: list[str] = []
    real_decode = bagport.episode.assemble._decode

    def spy(source: Any, message: Any) -> Any:
        decoded.append(message.topic)
        return real_decode(source, message)

    def no_encoder(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("a camera was encoded again")

    monkeypatch.setattr(bagport.episode.assemble, "_decode", spy)
    monkeypatch.setattr(bagport.episode.sinks, "StreamingEncoder", no_encoder)
    second = convert_episode(_request(bag, staging, FEWER_JOINTS))
    assert second.episode_id != first.episode_id
    assert second.reused_clips == {
        "observation.images.front": first.episode_id,
        "observation.images.wrist": first.episode_id,
    }
    assert set(decoded) == {"/joint_states", "/cmd"}  # no image message was even read
    state = {f.key: f for f in second.features}["observation.state"]
    assert (state.shape, state.names) == ((2,), ("position.j1", "position.j3"))
    for key in second.videos:
        assert (
            Path(second.file(second.videos[key])).read_bytes()
            == Path(first.file(first.videos[key])).read_bytes()
        )
    first_stats = json.loads(Path(first.file("stats.json")).read_text())
    second_stats = json.loads(Path(second.file("stats.json")).read_text())
    for key in second.videos:
        assert second_stats[key] == first_stats[key]
    checks = json.loads(Path(second.file("qa.json")).read_text())["checks"]
    camera_checks = {(c["check"], c["subject"]) for c in checks if c["subject"] in second.videos}
    assert ("video.psnr_min_db", "observation.images.front") in camera_checks
    assert ("values.frozen_image_s", "observation.images.wrist") in camera_checks

    out = tmp_path / "ds"  # the new contract's dataset, with the reused videos, loads in LeRobot
    write_dataset([second], str(out), robot_type="r")
    assert validate_dataset(out, repo_id="test/reuse").frames_decoded == second.frames


def test_a_changed_camera_setting_re_encodes_that_camera_only(tmp_path: Path) -> None:
    bag, staging = tmp_path / "ep", tmp_path / "staging"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5, cameras=CAMERAS))
    first = convert_episode(_request(bag, staging, SAMPLE_CONTRACT.read_text()))
    resized = convert_episode(_request(bag, staging, FRONT_RESIZED))
    assert resized.reused_clips == {"observation.images.wrist": first.episode_id}
    front = {f.key: f for f in resized.features}["observation.images.front"]
    assert front.shape == (16, 24, 3)


def test_an_episode_staged_by_another_bagport_version_is_converted_again(tmp_path: Path) -> None:
    bag, staging = tmp_path / "ep", tmp_path / "staging"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.3, cameras=CAMERAS))
    request = _request(bag, staging, SAMPLE_CONTRACT.read_text())
    first = convert_episode(request)
    assert convert_episode(request) == first  # same version: reused
    marker = Path(first.file("episode.json"))
    marker.write_text(json.dumps({**json.loads(marker.read_text()), "bagport_version": "0.0.1"}))
    again = convert_episode(request)
    assert again.bagport_version == first.bagport_version != "0.0.1"
    assert json.loads(marker.read_text())["bagport_version"] == first.bagport_version
