"""Cameras recorded as H.264 video (foxglove CompressedVideo with B-frames, FFMPEGPacket) convert like
any camera: every frame shows the capture index its alignment predicts on the header stamps."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq
import pytest

import bagport.episode.reuse
from bagport.dataset import write_dataset
from bagport.dataset.validate import validate_dataset, video_backend
from bagport.episode import convert_episode
from bagport.errors import AlignmentError
from bagport.staging import QA_FILE, EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, GroundTruth, decode_frame_index, write_episode_bag
from bagport.timewindow import TimeWindow
from bagport.video import iter_frames
from tests.helpers import episode_request

NS = 1_000_000_000
FPS = 30
FRONT = CameraSpec("front", "video", bframes=2, gop=30, jitter_ns=3_000_000, latency_ns=25_000_000)
WRIST = CameraSpec("wrist", "jpeg", jitter_ns=3_000_000, latency_ns=18_000_000)
SPEC = EpisodeSpec(duration_s=3.0, cameras=(FRONT, WRIST), seed=11)


def _contract(front: CameraSpec) -> str:
    return f"""\
robot_type: r
fps: {FPS}
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
  - key: observation.images.front
    topic: {front.topic}
    type: {front.msgtype}
    align: {{strategy: hold}}
  - key: observation.images.wrist
    topic: {WRIST.topic}
    type: {WRIST.msgtype}
    align: {{strategy: nearest, tol_ms: 20}}
actions:
  - key: action
    publish: {{topic: /cmd, type: sensor_msgs/msg/JointState}}
    selector: {{names: [j1, j2, j3, j4, j5, j6]}}
"""


def _held(stamps: npt.NDArray[np.int64], first_index: int, tick_ns: int) -> int:
    """Capture index of the newest decodable frame captured at or before the tick."""
    usable = stamps[first_index:]
    return first_index + int(np.searchsorted(usable, tick_ns, side="right")) - 1


def _nearest(stamps: npt.NDArray[np.int64], tick_ns: int) -> int:
    return int(np.argmin(np.abs(stamps - tick_ns)))


def _ticks(summary: EpisodeSummary) -> npt.NDArray[np.int64]:
    return summary.first_tick_ns + (np.arange(summary.frames, dtype=np.int64) * NS) // FPS


def _staged_codes(summary: EpisodeSummary, key: str) -> list[int]:
    return [
        decode_frame_index(rgb) for _, rgb in iter_frames(Path(summary.dir_uri) / "videos" / f"{key}.mp4")
    ]


def _qa(summary: EpisodeSummary) -> dict[tuple[str, str], dict[str, Any]]:
    qa = json.loads((Path(summary.dir_uri) / QA_FILE).read_text())
    return {(c["check"], c["subject"]): c for c in qa["checks"]}


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[GroundTruth, EpisodeSummary, Path]:
    root = tmp_path_factory.mktemp("video")
    truth = write_episode_bag(root / "ep", "mcap", SPEC)
    summary = convert_episode(episode_request(root / "ep", root / "staging", _contract(FRONT)))
    write_dataset([summary], str(root / "ds"), robot_type="r")
    return truth, summary, root / "ds"


@pytest.mark.slow
def test_lerobot_frames_show_the_predicted_capture_index(
    converted: tuple[GroundTruth, EpisodeSummary, Path],
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    truth, summary, out = converted
    report = validate_dataset(out, repo_id="test/video")
    assert report.frames_decoded == report.frames == summary.frames > 60
    dataset = LeRobotDataset("test/video", root=out, video_backend=video_backend())
    front_stamps, wrist_stamps = truth.camera_stamps_ns("front"), truth.camera_stamps_ns("wrist")
    for k, tick in enumerate(_ticks(summary).tolist()):
        item = dataset[k]
        assert _code(item["observation.images.front"]) == _held(front_stamps, 0, tick) % 1024, k
        assert _code(item["observation.images.wrist"]) == _nearest(wrist_stamps, tick) % 1024, k


def test_provenance_names_the_packet_and_qa_the_stream(
    converted: tuple[GroundTruth, EpisodeSummary, Path],
) -> None:
    truth, summary, _ = converted
    rows = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    front = [r for r in rows if r["key"] == "observation.images.front"]
    stamps = truth.camera_stamps_ns("front")
    assert len(front) == summary.frames
    for row in front:  # the packet's header stamp is the capture time of the frame it carried
        assert row["packet_index"] == row["message_index"]
        assert row["source_header_ns"] == stamps[_held(stamps, 0, row["tick_ns"])]
    assert all(r["packet_index"] is None for r in rows if r["key"] != "observation.images.front")
    checks = _qa(summary)
    assert checks[("video.skipped_packets", FRONT.topic)]["value"] == 0
    assert checks[("time.out_of_order", FRONT.topic)]["value"] == 0  # judged in capture order


def test_stream_starting_mid_gop_skips_to_its_first_key_frame(tmp_path: Path) -> None:
    front = replace(FRONT, kind="ffmpeg", skip_packets=7)
    spec = replace(SPEC, cameras=(front, WRIST))
    truth = write_episode_bag(tmp_path / "ep", "sqlite3", spec)
    summary = convert_episode(episode_request(tmp_path / "ep", tmp_path / "staging", _contract(front)))
    assert _qa(summary)[("video.skipped_packets", front.topic)]["value"] == 30 - 7
    stamps = truth.camera_stamps_ns("front")
    assert summary.first_tick_ns >= stamps[30]  # nothing before the key frame is a frame
    expected = [_held(stamps, 30, tick) % 1024 for tick in _ticks(summary).tolist()]
    assert _staged_codes(summary, "observation.images.front") == expected
    rows = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    front_rows = [r for r in rows if r["key"] == "observation.images.front"]
    assert all(r["packet_index"] == r["message_index"] + 23 for r in front_rows)


def test_window_starting_mid_gop_gives_the_frames_of_the_whole_bag(
    converted: tuple[GroundTruth, EpisodeSummary, Path], tmp_path: Path
) -> None:
    truth, whole, _ = converted
    bag = Path(whole.bag_uri)
    stamps = truth.camera_stamps_ns("front")
    start_ns = int(stamps[45])  # frame 45: halfway through the second GOP
    request = replace(
        episode_request(bag, tmp_path / "staging", _contract(FRONT)),
        window=TimeWindow.of_ns(start_ns, int(stamps[80])),
    )
    window = convert_episode(replace(request, episode_id=request.episode_id + "-w"))
    assert _qa(window)[("video.skipped_packets", FRONT.topic)]["value"] == 0
    assert window.first_tick_ns - start_ns < 40_000_000  # starts at the window, not at the next key frame
    whole_ticks, window_ticks = _ticks(whole), _ticks(window)
    whole_codes = _staged_codes(whole, "observation.images.front")
    window_codes = _staged_codes(window, "observation.images.front")
    assert window_codes == [_held(stamps, 0, tick) % 1024 for tick in window_ticks.tolist()]
    # and, tick for tick on the whole bag's grid, the same captured frames the whole conversion shows
    for code, tick in zip(window_codes, window_ticks.tolist(), strict=True):
        k = int(np.searchsorted(whole_ticks, tick, side="right")) - 1
        if _held(stamps, 0, int(whole_ticks[k])) == _held(stamps, 0, tick):
            assert whole_codes[k] == code


def _code(chw: Any) -> int:
    rgb = (chw.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    return decode_frame_index(rgb)


def test_clip_key_covers_the_video_decoder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    front = replace(FRONT, height=32, width=48)
    wrist = replace(WRIST, height=32, width=48)
    bag, staging = tmp_path / "ep", tmp_path / "staging"
    write_episode_bag(bag, "mcap", replace(SPEC, duration_s=1.0, cameras=(front, wrist)))
    text = _contract(front)
    first = convert_episode(episode_request(bag, staging, text))
    fewer = text.replace("names: [j1, j2, j3, j4, j5, j6]", "names: [j1, j2]", 1)
    second = convert_episode(episode_request(bag, staging, fewer))  # the video clip is reused
    assert second.reused_clips == dict.fromkeys(first.clip_keys, first.episode_id)
    other = {"decoder": "pyav", "av": "0.0", "libavcodec": (0, 0, 0)}
    monkeypatch.setattr(bagport.episode.reuse, "decoder_settings", lambda: other)
    third = convert_episode(
        episode_request(bag, staging, text.replace("[j1, j2, j3, j4, j5, j6]", "[j1]", 1))
    )
    assert set(third.reused_clips) == {"observation.images.wrist"}  # another decoder: decoded again
    assert third.clip_keys["observation.images.front"] != first.clip_keys["observation.images.front"]


def test_stream_without_a_key_frame_is_a_clear_error(tmp_path: Path) -> None:
    front = replace(FRONT, gop=300, skip_packets=1)  # one key frame, not recorded
    write_episode_bag(tmp_path / "ep", "mcap", replace(SPEC, duration_s=1.0, cameras=(front, WRIST)))
    with pytest.raises(
        AlignmentError, match=r"none of the 30 video packets on /front/video is a key frame.*Fix:"
    ):
        convert_episode(episode_request(tmp_path / "ep", tmp_path / "staging", _contract(front)))
