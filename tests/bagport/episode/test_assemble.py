"""Pass 2 on its own: prepare_episode's frozen alignment in, iter_frames' frames out, on synthetic bags."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags import BagMessage, open_bag
from bagport.contract import parse_contract
from bagport.decode import ImageKind
from bagport.episode import convert_episode
from bagport.episode.alignment import Alignment
from bagport.episode.assemble import iter_frames
from bagport.episode.prepare import prepare_episode
from bagport.errors import DecodeError
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import episode_request

NS = 1_000_000_000
H, W = 24, 32
DEPTH = CameraSpec("depth", "raw", "16UC1", height=H, width=W)
COLOUR = CameraSpec("front", "raw", "bgr8", height=H, width=W)


def _contract(camera: CameraSpec, fill: str = "fail") -> str:
    return yaml.safe_dump(
        {
            "robot_type": "r",
            "fps": 30,
            "observations": [
                {"key": "observation.state", "topic": "/joint_states", "type": "sensor_msgs/msg/JointState"},
                {
                    "key": "observation.images.cam",
                    "topic": camera.topic,
                    "type": camera.msgtype,
                    "image": {"resize": [H, W]},
                    "align": {"fill": fill},
                },
            ],
        }
    )


def _first_ticks_filled(alignment: Alignment, key: str, count: int) -> Alignment:
    """The alignment with ``key``'s first ``count`` ticks turned into zeros fills (before its first message)."""
    sources = []
    for source in alignment.sources:
        if source.src.key != key:
            sources.append(source)
            continue
        lo = source.selection.lo.copy()
        lo[:count] = -1
        filled = source.filled.copy()
        filled[:count] = True
        selection = dataclasses.replace(source.selection, lo=lo)
        sources.append(dataclasses.replace(source, selection=selection, filled=filled))
    return dataclasses.replace(alignment, sources=tuple(sources))


@pytest.mark.parametrize("camera", [DEPTH, COLOUR], ids=["depth", "colour"])
def test_a_zeros_fill_before_a_cameras_first_message_has_the_kind_of_its_messages(
    tmp_path: Path, camera: CameraSpec
) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5, cameras=(camera,), task=None, seed=3))
    text = _contract(camera, fill="zeros")
    plan = parse_contract(text, "c.yaml")
    with open_bag(str(bag)) as whole:
        prepared = prepare_episode(whole, plan, episode_request(bag, tmp_path / "st", text))
        alignment = _first_ticks_filled(prepared.alignment, "observation.images.cam", 3)
        assert prepared.alignment.sources[1].selection.lo[0] >= 0  # the prepared value is untouched
        frames = list(
            iter_frames(prepared.reader, str(bag), plan.features, alignment.sources, alignment.ticks_ns)
        )
    assert [f.index for f in frames] == list(range(alignment.frames))
    want = ImageKind.DEPTH if camera is DEPTH else ImageKind.COLOUR
    assert {f.kinds["observation.images.cam"] for f in frames} == {want}
    first, later = frames[0].images["observation.images.cam"], frames[5].images["observation.images.cam"]
    assert ImageKind.of(first) is want and ImageKind.of(later) is want
    assert first.shape == later.shape
    if want is ImageKind.DEPTH:
        assert np.isnan(first).all() and not np.isnan(later).all()  # invalid depth, not black colour
    else:
        assert first.max() == 0 and later.max() > 0
    assert frames[-1].names["observation.state"] == tuple(f"position.j{i}" for i in range(1, 7))


def test_frames_come_one_at_a_time_from_the_stream(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The generator yields the first frame before the bag is read to its end (nothing is collected)."""
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=2.0, cameras=(COLOUR,), task=None, seed=3))
    text = _contract(COLOUR)
    plan = parse_contract(text, "c.yaml")
    with open_bag(str(bag)) as whole:
        prepared = prepare_episode(whole, plan, episode_request(bag, tmp_path / "st", text))
        alignment = prepared.alignment
        read: list[int] = []
        real_messages = prepared.reader.messages

        def counting(*args: Any, **kwargs: Any) -> Iterator[BagMessage]:
            for message in real_messages(*args, **kwargs):
                read.append(message.log_time_ns)
                yield message

        monkeypatch.setattr(prepared.reader, "messages", counting)
        frames = iter_frames(prepared.reader, str(bag), plan.features, alignment.sources, alignment.ticks_ns)
        first = next(frames)
        assert first.index == 0
        assert read and max(read) < int(alignment.ticks_ns[5])
        assert sum(1 for _ in frames) == alignment.frames - 1


def _write_mixed_camera_bag(path: Path, frames: int) -> None:
    """``/cam`` at 30 Hz: depth (16UC1) for the first half of its messages, then colour (rgb8)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: Any = store.types
    start_ns = 1_700_000_000 * NS
    writer = Writer(path, version=9)
    writer.open()
    conn = writer.add_connection("/cam", "sensor_msgs/msg/Image", typestore=store)
    for i in range(frames):
        stamp_ns = start_ns + i * NS // 30
        depth = i < frames // 2
        pixels = np.full((H, W), 1000, np.uint16) if depth else np.full((H, W, 3), 100, np.uint8)
        msg = types["sensor_msgs/msg/Image"](
            header=types["std_msgs/msg/Header"](
                stamp=types["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS),
                frame_id="cam",
            ),
            height=H,
            width=W,
            encoding="16UC1" if depth else "rgb8",
            is_bigendian=0,
            step=W * (2 if depth else 3),
            data=pixels.view(np.uint8).ravel(),
        )
        writer.write(conn, stamp_ns, store.serialize_cdr(msg, "sensor_msgs/msg/Image"))
    writer.close()


def test_a_camera_whose_messages_turn_from_depth_to_colour_is_refused_where_it_turns(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    _write_mixed_camera_bag(bag, 12)
    text = yaml.safe_dump(
        {
            "robot_type": "r",
            "fps": 30,
            "default_task": "t",
            "observations": [
                {"key": "observation.images.cam", "topic": "/cam", "type": "sensor_msgs/msg/Image"}
            ],
        }
    )
    with pytest.raises(DecodeError) as caught:
        convert_episode(episode_request(bag, tmp_path / "st", text))
    err = caught.value
    assert (
        "observation.images.cam: this message decodes as a colour image, the messages before were depth"
        in str(err)
    )
    assert err.topic == "/cam"
    assert err.t_ns == 1_700_000_000 * NS + 6 * NS // 30  # the first colour message
    assert "contract.yaml:" in str(err) and "Fix: map depth and colour topics to different keys" in str(err)
    assert not (tmp_path / "st").exists() or not any((tmp_path / "st").rglob("episode.json"))
