"""Synthetic video cameras: one H.264 packet per message, stamped with the capture time of the frame
it carries; decoded frames show their capture index, B-frames reorder, a late start skips packets."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import av
import pytest

from bagport.bags import open_bag
from bagport.synth import CameraSpec, EpisodeSpec, decode_frame_index, write_episode_bag

SPEC = EpisodeSpec(duration_s=2.5, cameras=(), task=None, seed=3)


def _read(path: Path, topic: str) -> list[tuple[int, int | None, Any]]:
    with open_bag(str(path)) as reader:
        return [(m.log_time_ns, m.header_stamp_ns(), m.msg()) for m in reader.messages([topic])]


@pytest.mark.parametrize(
    ("kind", "storage", "bframes"),
    [("video", "mcap", 2), ("video", "ros1", 0), ("ffmpeg", "sqlite3", 2)],
    ids=["CompressedVideo-mcap-bframes", "CompressedVideo-ros1", "FFMPEGPacket-sqlite-bframes"],
)
def test_packets_decode_to_their_capture_index_and_stamp(
    tmp_path: Path, kind: Any, storage: Any, bframes: int
) -> None:
    cam = CameraSpec("front", kind, bframes=bframes, gop=30)
    path = tmp_path / ("ep.bag" if storage == "ros1" else "ep")
    truth = write_episode_bag(path, storage, replace(SPEC, cameras=(cam,)))
    stamps = truth.camera_stamps_ns("front")
    messages = _read(path, cam.topic)
    assert len(messages) == stamps.size
    logs = [log for log, _, _ in messages]
    assert logs == sorted(logs)
    decoder: Any = av.CodecContext.create("h264", "r")
    shown: dict[int, int] = {}
    for j, (_, _, msg) in enumerate(messages):
        packet = av.Packet(bytes(msg.data))
        packet.pts = j
        for frame in decoder.decode(packet):
            shown[int(frame.pts)] = decode_frame_index(frame.to_ndarray(format="rgb24"))
    for frame in decoder.decode(None):
        shown[int(frame.pts)] = decode_frame_index(frame.to_ndarray(format="rgb24"))
    assert sorted(shown) == list(range(len(messages)))
    for j, (_, header_ns, _) in enumerate(messages):  # each message is stamped with its frame's capture time
        assert header_ns == stamps[shown[j]]
    reordered = [shown[j] for j in range(len(messages))] != list(range(len(messages)))
    assert reordered == (bframes > 0)


def test_stream_starting_mid_gop_lacks_its_first_packets(tmp_path: Path) -> None:
    cam = CameraSpec("front", "video", bframes=2, gop=30, skip_packets=7)
    truth = write_episode_bag(tmp_path / "ep", "mcap", replace(SPEC, cameras=(cam,)))
    messages = _read(tmp_path / "ep", cam.topic)
    assert len(messages) == truth.camera_stamps_ns("front").size - 7
