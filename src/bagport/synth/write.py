"""Write synthetic episodes as rosbag2 (MCAP, SQLite) or ROS 1 bags with rosbags' writers."""

from __future__ import annotations

import io
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import simplejpeg
import yaml
from PIL import Image as PILImage
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags.bundled import BUNDLED_DEFINITIONS
from bagport.bags.typesources import parse_msg_definitions
from bagport.errors import BagportError
from bagport.synth.images import compressed_depth_payload, depth_frame, raw_depth_bytes, raw_image_bytes
from bagport.synth.pixels import render_frame
from bagport.synth.publish import rewrite_publish_times
from bagport.synth.spec import CameraSpec, EpisodeSpec
from bagport.synth.truth import GroundTruth
from bagport.synth.video import VideoPacket, encode_video

__all__ = ["SynthStorage", "write_episode_bag", "write_sample_fleet"]

SynthStorage = Literal["mcap", "sqlite3", "ros1"]
NS = 1_000_000_000
OPERATOR_PROMPT_KEY = "lerobot.operator_prompt"


class _Messages:
    """Builds messages with the right type store (ROS 1 headers carry ``seq``)."""

    def __init__(self, ros1: bool) -> None:
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        self.store.register(parse_msg_definitions(BUNDLED_DEFINITIONS))
        self.ros1 = ros1
        self.serialize: Callable[[Any, str], bytes | memoryview] = (
            self.store.serialize_ros1 if ros1 else self.store.serialize_cdr
        )
        types = self.store.types
        self._time = types["builtin_interfaces/msg/Time"]
        self._header = types["std_msgs/msg/Header"]
        self.joint_state = types["sensor_msgs/msg/JointState"]
        self.image = types["sensor_msgs/msg/Image"]
        self.compressed = types["sensor_msgs/msg/CompressedImage"]
        self.string = types["std_msgs/msg/String"]
        self.bool = types["std_msgs/msg/Bool"]
        self.video = types["foxglove_msgs/msg/CompressedVideo"]
        self.ffmpeg = types["ffmpeg_image_transport_msgs/msg/FFMPEGPacket"]

    def header(self, stamp_ns: int, seq: int, frame_id: str) -> Any:
        stamp = self._time(sec=stamp_ns // NS, nanosec=stamp_ns % NS)
        if self.ros1:
            return self._header(seq=seq, stamp=stamp, frame_id=frame_id)
        return self._header(stamp=stamp, frame_id=frame_id)


def _camera_pixels(
    spec: EpisodeSpec, cam: CameraSpec, k: int, stamp_ns: int, rng: np.random.Generator
) -> npt.NDArray[np.uint8]:
    faults = spec.faults
    black, frozen = faults.black_frames, faults.frozen_camera
    if black is not None and black.camera == cam.name and black.contains(stamp_ns, spec.start_ns):
        return np.zeros((cam.height, cam.width, 3), dtype=np.uint8)
    if frozen is not None and frozen.camera == cam.name and frozen.contains(stamp_ns, spec.start_ns):
        k = round(frozen.start_s * cam.rate_hz)  # the frame captured when the driver stalled, without noise
        return render_frame(cam.height, cam.width, k, np.random.default_rng(k), cam.noise)
    return render_frame(cam.height, cam.width, k, rng, cam.noise)


def _camera_message(
    msgs: _Messages, spec: EpisodeSpec, cam: CameraSpec, k: int, stamp_ns: int, rng: np.random.Generator
) -> Any:
    header = msgs.header(stamp_ns, k, cam.name)
    if cam.is_depth:
        depth = depth_frame(cam.height, cam.width, k)
        if cam.kind == "compressed_depth":
            payload, fmt = compressed_depth_payload(depth, cam.encoding, cam.depth_codec)
            return msgs.compressed(header=header, format=fmt, data=np.frombuffer(payload, dtype=np.uint8))
        data, step = raw_depth_bytes(depth, cam.encoding)
        return msgs.image(
            header=header,
            height=cam.height,
            width=cam.width,
            encoding=cam.encoding,
            is_bigendian=0,
            step=step,
            data=data,
        )
    rgb = _camera_pixels(spec, cam, k, stamp_ns, rng)
    if cam.kind == "raw":
        data, step = raw_image_bytes(rgb, cam.encoding)
        return msgs.image(
            header=header,
            height=cam.height,
            width=cam.width,
            encoding=cam.encoding,
            is_bigendian=0,
            step=step,
            data=data,
        )
    if cam.kind == "jpeg":
        payload = simplejpeg.encode_jpeg(rgb, quality=90, colorspace="RGB")
        fmt = "rgb8; jpeg compressed bgr8"
    else:
        buf = io.BytesIO()
        PILImage.fromarray(rgb).save(buf, format="PNG")
        payload, fmt = buf.getvalue(), "png"
    return msgs.compressed(header=header, format=fmt, data=np.frombuffer(payload, dtype=np.uint8))


def _video_packets(spec: EpisodeSpec, truth: GroundTruth) -> dict[str, list[VideoPacket]]:
    """Every packet of each video camera, in decode order (frames rendered from capture indices)."""
    out = {}
    for index, cam in enumerate(spec.cameras):
        if cam.is_video:
            rng = np.random.default_rng(spec.seed + 100 + index)
            count = truth.camera_stamps_ns(cam.name).size
            frames = (render_frame(cam.height, cam.width, k, rng, cam.noise) for k in range(count))
            out[cam.topic] = list(
                encode_video(
                    frames,
                    width=cam.width,
                    height=cam.height,
                    fps=cam.rate_hz,
                    bframes=cam.bframes,
                    gop=cam.gop,
                )
            )
    return out


def _video_message(msgs: _Messages, cam: CameraSpec, packet: VideoPacket, k: int, stamp_ns: int) -> Any:
    data = np.frombuffer(packet.data, dtype=np.uint8)
    if cam.kind == "video":
        stamp = msgs.header(stamp_ns, 0, cam.name).stamp
        return msgs.video(timestamp=stamp, frame_id=cam.name, data=data, format="h264")
    return msgs.ffmpeg(
        header=msgs.header(stamp_ns, k, cam.name), width=cam.width, height=cam.height, encoding="libx264",
        pts=packet.pts, flags=int(packet.keyframe), is_bigendian=False, data=data,
    )  # fmt: skip


def _video_events(
    cam: CameraSpec, stamps: npt.NDArray[np.int64], packets: list[VideoPacket]
) -> list[tuple[int, str, int, int]]:
    """Packet ``j`` leaves the encoder when frame ``j + bframes`` is captured; it is stamped with the
    capture time of the frame it carries."""
    last = stamps.size - 1
    return [
        (int(stamps[min(j + cam.bframes, last)]) + cam.latency_ns, cam.topic, j, int(stamps[packet.pts]))
        for j, packet in enumerate(packets)
        if j >= cam.skip_packets
    ]


def _joint_position(truth: GroundTruth, stamp_ns: int) -> npt.NDArray[np.float64]:
    spec, faults = truth.spec, truth.spec.faults
    frozen = faults.frozen_joints
    if frozen is not None and frozen.contains(stamp_ns, spec.start_ns):
        stamp_ns = spec.start_ns + round(frozen.start_s * NS)
    pos = truth.joint_position(stamp_ns).copy()
    t_s = (stamp_ns - spec.start_ns) / NS
    if faults.joint_spike is not None and faults.joint_spike[0] <= t_s < faults.joint_spike[0] + 0.1:
        pos += faults.joint_spike[1]
    if faults.joint_nan_at_s is not None and faults.joint_nan_at_s <= t_s < faults.joint_nan_at_s + 0.05:
        pos[:] = np.nan
    return pos


def _joint_message(msgs: _Messages, truth: GroundTruth, k: int, stamp_ns: int, header_ns: int) -> Any:
    names = list(truth.spec.joint_names)
    pos, vel, eff = (
        _joint_position(truth, stamp_ns),
        truth.joint_velocity(stamp_ns),
        truth.joint_effort(stamp_ns),
    )
    if k % 2:  # the order of names differs between messages: consumers must select by name
        names, pos, vel, eff = names[::-1], pos[::-1], vel[::-1], eff[::-1]
    return msgs.joint_state(
        header=msgs.header(header_ns, k, "base"),
        name=names,
        position=np.ascontiguousarray(pos, dtype=np.float64),
        velocity=np.ascontiguousarray(vel, dtype=np.float64),
        effort=np.ascontiguousarray(eff, dtype=np.float64),
    )


def _action_message(msgs: _Messages, truth: GroundTruth, k: int, stamp_ns: int) -> Any:
    return msgs.joint_state(
        header=msgs.header(stamp_ns, k, "base"),
        name=list(truth.spec.joint_names),
        position=np.ascontiguousarray(truth.action_position(stamp_ns), dtype=np.float64),
        velocity=np.zeros(0, dtype=np.float64),
        effort=np.zeros(0, dtype=np.float64),
    )


def _events(truth: GroundTruth, video: dict[str, list[VideoPacket]]) -> Iterator[tuple[int, str, int, int]]:
    """(log_ns, topic, index, stamp_ns) for every message, in log-time order (video cameras: the
    index of the packet in decode order)."""
    spec = truth.spec
    events: list[tuple[int, str, int, int]] = []

    def paused(stamp: int) -> bool:
        return any(pause.contains(stamp, spec.start_ns) for pause in spec.pauses)

    for k, stamp in enumerate(truth.joint_stamps_ns().tolist()):
        if not paused(stamp):
            events.append((stamp + spec.joint_latency_ns, spec.JOINT_TOPIC, k, stamp))
    for k, stamp in enumerate(truth.action_stamps_ns().tolist()):
        if not paused(stamp):
            events.append((stamp + spec.action_latency_ns, spec.ACTION_TOPIC, k, stamp))
    dropout = spec.faults.camera_dropout
    for cam in spec.cameras:
        if cam.is_video:  # a whole stream: no dropout or pause cuts it
            events += _video_events(cam, truth.camera_stamps_ns(cam.name), video[cam.topic])
            continue
        for k, stamp in enumerate(truth.camera_stamps_ns(cam.name).tolist()):
            if dropout is not None and dropout.camera == cam.name and dropout.contains(stamp, spec.start_ns):
                continue
            if not paused(stamp):
                events.append((stamp + cam.latency_ns, cam.topic, k, stamp))
    for k, (t_s, _) in enumerate(spec.prompts, start=1):
        stamp = spec.start_ns + round(t_s * NS)
        events.append((stamp, spec.TASK_TOPIC, k, stamp))
    for k, (t_s, _) in enumerate(spec.events):
        stamp = spec.start_ns + round(t_s * NS)
        events.append((stamp, spec.EVENTS_TOPIC, k, stamp))
    for k, t_s in enumerate(spec.done_at_s):
        stamp = spec.start_ns + round(t_s * NS)
        events += [
            (stamp, spec.DONE_TOPIC, 2 * k, stamp),
            (stamp + NS // 20, spec.DONE_TOPIC, 2 * k + 1, stamp),
        ]
    if spec.faults.estop_at_s is not None:
        for k in range(int(spec.duration_s * 10) + 1):
            stamp = spec.start_ns + k * NS // 10
            events.append((stamp, spec.faults.ESTOP_TOPIC, k, stamp))
    if spec.task is not None:
        events.append((truth.task_stamp_ns, spec.TASK_TOPIC, 0, truth.task_stamp_ns))
    events.sort()
    return iter(events)


def _topic_types(spec: EpisodeSpec) -> dict[str, str]:
    """Each topic the episode records, and its message type."""
    types = {spec.JOINT_TOPIC: "sensor_msgs/msg/JointState", spec.ACTION_TOPIC: "sensor_msgs/msg/JointState"}
    types.update({cam.topic: cam.msgtype for cam in spec.cameras})
    if spec.task is not None:
        types[spec.TASK_TOPIC] = "std_msgs/msg/String"
    if spec.faults.estop_at_s is not None:
        types[spec.faults.ESTOP_TOPIC] = "std_msgs/msg/Bool"
    if spec.events:
        types[spec.EVENTS_TOPIC] = "std_msgs/msg/String"
    if spec.done_at_s:
        types[spec.DONE_TOPIC] = "std_msgs/msg/Bool"
    return types


def write_episode_bag(path: Path, storage: SynthStorage, spec: EpisodeSpec) -> GroundTruth:
    """Write one episode; mcap/sqlite3 make a rosbag2 folder at ``path``, ros1 a ``.bag`` file."""
    truth = GroundTruth(spec)
    msgs = _Messages(ros1=storage == "ros1")
    cameras = {cam.topic: cam for cam in spec.cameras}
    types = _topic_types(spec)
    joint_header_ns = spec.faults.joint_header_ns(truth.joint_stamps_ns())
    rng = np.random.default_rng(spec.seed + 1)
    video = _video_packets(spec, truth)
    writer: Any
    if storage == "ros1":
        writer = Ros1Writer(path)
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    writer.open()
    try:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=msgs.store)
            for topic, msgtype in types.items()
        }
        if storage != "ros1" and spec.task is not None:
            writer.set_custom_data(OPERATOR_PROMPT_KEY, spec.task)
        for log_ns, topic, k, stamp in _events(truth, video):
            if topic == spec.JOINT_TOPIC:
                msg = _joint_message(msgs, truth, k, stamp, int(joint_header_ns[k]))
            elif topic == spec.ACTION_TOPIC:
                msg = _action_message(msgs, truth, k, stamp)
            elif topic == spec.TASK_TOPIC:
                msg = msgs.string(data=spec.prompts[k - 1][1] if k else spec.task or "")
            elif topic == spec.EVENTS_TOPIC:
                msg = msgs.string(data=spec.events[k][1])
            elif topic == spec.DONE_TOPIC:
                msg = msgs.bool(data=k % 2 == 0)
            elif topic == spec.faults.ESTOP_TOPIC:
                estop_s = spec.faults.estop_at_s or 0.0
                msg = msgs.bool(data=estop_s <= (stamp - spec.start_ns) / NS < estop_s + 0.5)
            elif topic in video:
                msg = _video_message(msgs, cameras[topic], video[topic][k], k, stamp)
            else:
                msg = _camera_message(msgs, spec, cameras[topic], k, stamp, rng)
            writer.write(conns[topic], log_ns, msgs.serialize(msg, types[topic]))
    finally:
        writer.close()
    if storage == "mcap" and (spec.publish_lag_ns is not None or spec.mcap_crcs):
        lag_ns = spec.publish_lag_ns
        for file in sorted(path.glob("*.mcap")):
            times = (
                ()
                if lag_ns is None
                else ((t, log, stamp + lag_ns) for log, t, _, stamp in _events(truth, video))
            )
            rewrite_publish_times(file, times, crcs=spec.mcap_crcs)
    return truth


_STORAGES: tuple[SynthStorage, ...] = ("mcap", "sqlite3", "ros1")
_TASKS = ("pick up the red cube", "place the cube in the bin")


def write_sample_fleet(
    out_dir: Path,
    *,
    episodes: int = 4,
    duration_s: float = 3.0,
    seed: int = 0,
    cameras: tuple[CameraSpec, ...] | None = None,
) -> list[Path]:
    """A small fleet cycling MCAP folder, SQLite folder and ROS 1 .bag, plus ``manifest.yaml``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    entries = []
    for index in range(episodes):
        storage = _STORAGES[index % len(_STORAGES)]
        name = f"episode_{index:03d}" + (".bag" if storage == "ros1" else "")
        path = out_dir / name
        if path.exists():
            raise BagportError(
                f"{path} already exists; nothing was written. Fix: choose an empty --out folder."
            )
        spec = EpisodeSpec(
            duration_s=duration_s,
            start_ns=1_700_000_000_000_000_000 + index * 3_600 * NS,
            seed=seed + index,
            task=_TASKS[index % len(_TASKS)],
            mcap_crcs=storage == "mcap",  # as `ros2 bag record` writes MCAP: chunk CRCs for reads to check
        )
        if cameras is not None:
            spec = replace(spec, cameras=cameras)
        write_episode_bag(path, storage, spec)
        paths.append(path)
        entries.append({"uri": name, "metadata": {"storage": storage, "seed": seed + index}})
    manifest = {"bags": entries}
    (out_dir / "manifest.yaml").write_text(
        "# Written by `bagport synth`: one bag per episode, paths relative to this file.\n"
        + yaml.safe_dump(manifest, sort_keys=False)
    )
    return paths
