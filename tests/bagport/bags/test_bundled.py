"""Camera video types (foxglove CompressedVideo, ffmpeg_image_transport FFMPEGPacket) read without
any definition in the bag or on --msg-path; CompressedVideo's ``timestamp`` is its header stamp."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from bagport.bags import open_bag
from bagport.bags.bundled import BUNDLED_DEFINITIONS
from bagport.bags.typesources import parse_msg_definitions
from bagport.msgtypes import RosType
from tests.bagport.decode.bagwriter import write_bag

START_NS = 1_700_000_000_123_000_000
VIDEO, PACKET = RosType.COMPRESSED_VIDEO.value, RosType.FFMPEG_PACKET.value


def _store(ros1: bool) -> Any:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(parse_msg_definitions(BUNDLED_DEFINITIONS))
    return store


def _streams(store: Any, ros1: bool) -> list[tuple[str, str, list[tuple[int, Any]]]]:
    t = store.types
    videos, packets = [], []
    for k in range(3):
        stamp_ns = START_NS + k * 33_000_000
        stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        header = t["std_msgs/msg/Header"](**({"seq": k} if ros1 else {}), stamp=stamp, frame_id="cam")
        data = np.arange(k + 4, dtype=np.uint8)
        videos.append(
            (stamp_ns + 5_000_000, t[VIDEO](timestamp=stamp, frame_id="cam", data=data, format="h264"))
        )
        packet = t[PACKET](
            header=header, width=64, height=48, encoding="libx264", pts=k, flags=int(k == 0),
            is_bigendian=False, data=data,
        )  # fmt: skip
        packets.append((stamp_ns + 7_000_000, packet))
    return [("/cam/video", VIDEO, videos), ("/cam/image_raw/ffmpeg", PACKET, packets)]


@pytest.mark.parametrize("storage", ["sqlite3", "ros1"])
def test_video_types_read_without_definitions(tmp_path: Path, storage: Literal["sqlite3", "ros1"]) -> None:
    ros1 = storage == "ros1"
    store = _store(ros1)
    bag = write_bag(tmp_path / "bag", storage, store, _streams(store, ros1))
    if not ros1:  # a Humble recording embeds no definitions: the bundle must supply them
        with sqlite3.connect(next(bag.glob("*.db3"))) as con:
            con.execute("DELETE FROM message_definitions")
    with open_bag(str(bag)) as reader:
        assert reader.undefined_types == {}
        seen: dict[str, list[tuple[int | None, Any]]] = {}
        for message in reader.messages(["/cam/video", "/cam/image_raw/ffmpeg"]):
            seen.setdefault(message.topic, []).append((message.header_stamp_ns(), message.msg()))
    stamps = [START_NS + k * 33_000_000 for k in range(3)]
    assert [s for s, _ in seen["/cam/video"]] == stamps
    assert [s for s, _ in seen["/cam/image_raw/ffmpeg"]] == stamps
    assert [m.format for _, m in seen["/cam/video"]] == ["h264"] * 3
    assert [bytes(m.data) for _, m in seen["/cam/image_raw/ffmpeg"]] == [
        bytes(range(k + 4)) for k in range(3)
    ]
    assert [m.encoding for _, m in seen["/cam/image_raw/ffmpeg"]] == ["libx264"] * 3
