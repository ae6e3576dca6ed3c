"""The LeRobot-writer baseline: a straightforward converter as users write it today.

rosbags reads each bag in log order, the latest message of every topic is held, and at every 1/fps
tick a frame goes to ``LeRobotDataset.add_frame``; ``save_episode`` per bag, ``finalize`` at the end.
Default mode, or ``--streaming`` (``streaming_encoding=True``).

Usage: python bench/baseline_lerobot.py WORKLOAD_DIR OUT [--streaming]
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from PIL import Image
from rosbags.highlevel import AnyReader

NS = 1_000_000_000


def _features(contract: dict[str, Any], first: dict[str, Any]) -> dict[str, Any]:
    features: dict[str, Any] = {}
    for entry in contract["observations"]:
        if "images" in entry["key"]:
            h, w = first[entry["topic"]].shape[:2]
            features[entry["key"]] = {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
            }
        else:
            names = [n.split(".", 1)[1] for n in entry["selector"]["names"]]
            features[entry["key"]] = {"dtype": "float32", "shape": [len(names)], "names": names}
    names = [n.split(".", 1)[1] for n in contract["actions"][0]["selector"]["names"]]
    features["action"] = {"dtype": "float32", "shape": [len(names)], "names": names}
    return features


def _decode(msgtype: str, msg: Any, joints: list[str]) -> Any:
    if msgtype == "sensor_msgs/msg/Image":
        array = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)
        return array[:, :, ::-1] if msg.encoding == "bgr8" else array
    if msgtype == "sensor_msgs/msg/CompressedImage":
        return np.asarray(Image.open(io.BytesIO(msg.data.tobytes())).convert("RGB"))
    if msgtype == "sensor_msgs/msg/JointState":
        order = {name: i for i, name in enumerate(msg.name)}
        return np.array([msg.position[order[j]] for j in joints], dtype=np.float32)
    return str(msg.data)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("workload", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--streaming", action="store_true")
    args = parser.parse_args()
    contract = yaml.safe_load((args.workload / "contract.yaml").read_text())
    bags = [
        args.workload / b["uri"]
        for b in yaml.safe_load((args.workload / "manifest.yaml").read_text())["bags"]
    ]
    fps = int(contract["fps"])
    keys = {e["topic"]: e["key"] for e in contract["observations"]}
    keys[contract["actions"][0]["publish"]["topic"]] = "action"
    task_topic = contract["tasks"][0]["topic"]
    joints = [n.split(".", 1)[1] for n in contract["observations"][0]["selector"]["names"]]
    dataset: LeRobotDataset | None = None
    for bag in bags:
        latest: dict[str, Any] = {}
        task = ""
        next_tick: int | None = None
        with AnyReader([bag]) as reader:
            conns = [c for c in reader.connections if c.topic in keys or c.topic == task_topic]
            for conn, t_ns, raw in reader.messages(connections=conns):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                if conn.topic == task_topic:
                    task = str(msg.data)
                    continue
                while next_tick is not None and t_ns >= next_tick:  # emit every tick passed, holding values
                    if dataset is None:
                        dataset = LeRobotDataset.create(
                            "bench/baseline", fps, _features(contract, latest), root=args.out,
                            robot_type="bench_arm", streaming_encoding=args.streaming,
                        )  # fmt: skip
                    dataset.add_frame({keys[t]: v for t, v in latest.items()} | {"task": task})
                    next_tick += NS // fps
                latest[conn.topic] = _decode(conn.msgtype, msg, joints)
                if next_tick is None and len(latest) == len(keys):
                    next_tick = t_ns
        assert dataset is not None
        dataset.save_episode()
    assert dataset is not None
    dataset.finalize()


if __name__ == "__main__":
    main()
