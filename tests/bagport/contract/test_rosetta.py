"""Rosetta compatibility: its README's contract examples load unchanged, and the DROID pattern
(split sub-keys next to the combined state) converts to consistent columns."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import simplejpeg
from rosbags.typesys import Stores, get_typestore

from bagport.config import ConvertConfig
from bagport.contract import FeatureKind, parse_contract
from bagport.dataset.validate import validate_dataset
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.bagport.decode.bagwriter import Stream, write_bag

# Every section and entry field of Rosetta's contract reference, as its README writes them
# (see /work/shared/ROSETTA_CONTRACT.md), including its placeholder decoder module.
ROSETTA_FULL = """\
robot_type: so101
fps: 30
max_duration_s: 120.0
timestamp_source: receive
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector:
      names: [position.j1, velocity.j1]
    align:
      strategy: hold
      tol_ms: 50
      stamp: header
    dtype: float32
    qos: {reliability: best_effort, depth: 10}
  - key: observation.custom
    topic: /my_sensor
    type: std_msgs/msg/Float64MultiArray
    decoder: my_pkg.converters:decode_my_sensor
    align: {strategy: asof, tol_ms: 50, stamp: receive}
  - key: observation.images.top
    topic: /camera/image_raw/compressed
    type: sensor_msgs/msg/CompressedImage
    image:
      resize: [224, 224]
actions:
  - key: action
    publish:
      topic: /joint_commands
      type: sensor_msgs/msg/JointState
      qos: {reliability: reliable, depth: 10}
    selector:
      names: [position.j1, position.j2]
    safety_behavior: hold
    decoder: my_pkg.converters:decode_my_sensor
    encoder: my_pkg.converters:encode_my_command
tasks:
  - key: task
    topic: /task_prompt
    type: std_msgs/msg/String
rewards:
  - key: next.reward
    topic: /reward
    type: std_msgs/msg/Float64
    dtype: float32
signals:
  - key: next.done
    topic: /done
    type: std_msgs/msg/Bool
    dtype: bool
  - key: next.truncated
    topic: /truncated
    type: std_msgs/msg/Bool
    dtype: bool
complementary_data:
  - key: complementary_info.discrete_penalty
    topic: /penalty
    type: std_msgs/msg/Float32
    dtype: float32
adjunct:
  - topic: /tf
    type: tf2_msgs/msg/TFMessage
  - topic: /diagnostics
    type: diagnostic_msgs/msg/DiagnosticArray
teleop: {leader: /leader/joint_states}
reset: {service: /reset}
visualization: {rviz: true}
recording: {storage: mcap}
info: {description: arm}
"""

CONVERTERS = """\
import numpy as np


def decode_my_sensor(msg, spec):
    # Rosetta's decoder spec: spec.msg_type and spec.names
    if spec.msg_type == "sensor_msgs/msg/JointState":
        joints = list(msg.name)
        return np.array([msg.position[joints.index(n.split(".")[1])] for n in spec.names])
    if spec.msg_type == "std_msgs/msg/Float64MultiArray":
        return 10.0 * np.asarray(msg.data, dtype=np.float64)
    raise TypeError(spec.msg_type)


def encode_my_command(values, spec):
    return None
"""


@pytest.fixture
def my_pkg(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rosetta's placeholder decoder module, on the path (how a worker finds a local decoder)."""
    package = tmp_path / "my_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "converters.py").write_text(CONVERTERS)
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("my_pkg", "my_pkg.converters"):  # another test's copy must not be reused
        monkeypatch.delitem(sys.modules, name, raising=False)


@pytest.mark.usefixtures("my_pkg")
def test_rosetta_readme_contract_loads_unchanged() -> None:
    plan = parse_contract(ROSETTA_FULL, "rosetta.yaml")
    assert [(f.key, f.kind, f.dtype) for f in plan.features] == [
        ("observation.state", FeatureKind.VECTOR, "float32"),
        ("observation.custom", FeatureKind.VECTOR, "float32"),
        ("observation.images.top", FeatureKind.VIDEO, "video"),
        ("action", FeatureKind.VECTOR, "float32"),
        ("next.reward", FeatureKind.VECTOR, "float32"),
        ("next.done", FeatureKind.VECTOR, "bool"),
        ("next.truncated", FeatureKind.VECTOR, "bool"),
        ("complementary_info.discrete_penalty", FeatureKind.VECTOR, "float32"),
    ]
    sources = {s.key: s for s in plan.sources}
    assert sources["action"].stamp == "receive"  # timestamp_source applies to actions
    assert sources["observation.state"].stamp == "header"
    assert sources["observation.custom"].decoder == "my_pkg.converters:decode_my_sensor"
    assert sources["observation.images.top"].resize_hw == (224, 224)
    assert "/tf" not in plan.topics()  # adjunct topics are recorded, not mapped
    assert [t.topic for t in plan.task_topics] == ["/task_prompt"]


TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
FPS = 30
FRAMES = 30
START_NS = 1_700_000_000_000_000_000
RGB = (200, 30, 60)  # red-dominant, blue second: a BGR/RGB swap shows


def _header(t_ns: int) -> Any:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="base"
    )


def _joints(t_ns: int, names: list[str], values: list[float]) -> Any:
    return T["sensor_msgs/msg/JointState"](
        header=_header(t_ns),
        name=names,
        position=np.array(values),
        velocity=-np.array(values),
        effort=np.zeros(len(values)),
    )


def _rosetta_streams() -> list[Stream]:
    """Every topic ROSETTA_FULL maps, frame k's values a function of k."""
    ticks = [START_NS + k * 1_000_000_000 // FPS for k in range(FRAMES)]  # the grid's own ticks
    jpeg = simplejpeg.encode_jpeg(np.full((48, 64, 3), RGB, np.uint8), quality=95, colorspace="RGB")
    layout = T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)

    def per_tick(topic: str, msgtype: str, make: Any) -> Stream:
        return (topic, msgtype, [(t, make(k, t)) for k, t in enumerate(ticks)])

    return [
        per_tick("/joint_states", "sensor_msgs/msg/JointState", lambda k, t: _joints(t, ["j1"], [k / 10])),
        per_tick(
            "/my_sensor",
            "std_msgs/msg/Float64MultiArray",
            lambda k, t: T["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.array([k, -k / 2])),
        ),
        per_tick(
            "/camera/image_raw/compressed",
            "sensor_msgs/msg/CompressedImage",
            lambda k, t: T["sensor_msgs/msg/CompressedImage"](
                header=_header(t), format="jpeg", data=np.frombuffer(jpeg, np.uint8)
            ),
        ),
        per_tick(
            "/joint_commands",
            "sensor_msgs/msg/JointState",
            lambda k, t: _joints(t, ["j2", "j1"], [-k / 4, k / 5]),
        ),
        (
            "/task_prompt",
            "std_msgs/msg/String",
            [(START_NS, T["std_msgs/msg/String"](data="stack the cups"))],
        ),
        per_tick("/reward", "std_msgs/msg/Float64", lambda k, t: T["std_msgs/msg/Float64"](data=k / 29)),
        per_tick("/done", "std_msgs/msg/Bool", lambda k, t: T["std_msgs/msg/Bool"](data=k == FRAMES - 1)),
        per_tick("/truncated", "std_msgs/msg/Bool", lambda k, t: T["std_msgs/msg/Bool"](data=False)),
        per_tick("/penalty", "std_msgs/msg/Float32", lambda k, t: T["std_msgs/msg/Float32"](data=-0.5 * k)),
    ]


@pytest.mark.slow
@pytest.mark.usefixtures("my_pkg")
def test_rosetta_readme_contract_converts_unchanged(tmp_path: Path) -> None:
    """Every section, the entry decoders (reading spec.msg_type/spec.names), resize and bool signals."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = write_bag(tmp_path / "rosetta_ep", "mcap", TS, _rosetta_streams())
    contract = tmp_path / "rosetta.yaml"
    contract.write_text(ROSETTA_FULL)
    config = ConvertConfig(
        bags_glob=str(bag), contract=str(contract), output=str(tmp_path / "ds"), on_qa_fail="keep"
    )
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    assert validate_dataset(tmp_path / "ds", repo_id="test/rosetta").frames == FRAMES
    dataset = LeRobotDataset("test/rosetta", root=tmp_path / "ds")
    features = dataset.meta.features
    assert features["next.done"]["dtype"] == "bool"
    assert features["observation.images.top"]["shape"] == (224, 224, 3)
    assert features["action"]["names"] == ["position.j1", "position.j2"]
    for k in range(FRAMES):
        item = dataset[k]
        assert item["task"] == "stack the cups"
        np.testing.assert_allclose(item["observation.state"].numpy(), [k / 10, -k / 10], rtol=1e-6)
        np.testing.assert_allclose(item["observation.custom"].numpy(), [10 * k, -5 * k], rtol=1e-6)
        np.testing.assert_allclose(item["action"].numpy(), [k / 5, -k / 4], rtol=1e-6)
        assert float(item["next.reward"]) == pytest.approx(k / 29, rel=1e-6)
        assert bool(item["next.done"]) is (k == FRAMES - 1)
        assert bool(item["next.truncated"]) is False
        assert float(item["complementary_info.discrete_penalty"]) == -0.5 * k
        image = item["observation.images.top"].numpy()  # (3, H, W) in [0, 1], RGB
        np.testing.assert_allclose(image.reshape(3, -1).mean(axis=1) * 255, RGB, atol=6)


DROID = """\
robot_type: droid_like
fps: 15
observations:
  - key: observation.state.joint_position
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {names: [position.j1, position.j2, position.j3, position.j4, position.j5]}
  - key: observation.state.gripper_position
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {names: [position.j6]}
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {names: [position.j1, position.j2, position.j3, position.j4, position.j5]}
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector: {names: [position.j6]}
actions:
  - key: action
    publish: {topic: /cmd, type: sensor_msgs/msg/JointState}
    selector: {names: [position.j1, position.j2, position.j3, position.j4, position.j5, position.j6]}
"""


@pytest.mark.slow
def test_droid_split_sub_keys_and_combined_state(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=1.0, cameras=()))
    contract = tmp_path / "droid.yaml"
    contract.write_text(DROID)
    config = ConvertConfig(
        bags_glob=str(tmp_path / "ep"),
        contract=str(contract),
        output=str(tmp_path / "ds"),
        on_qa_fail="keep",
    )
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    dataset = LeRobotDataset("test/droid", root=tmp_path / "ds")
    features = dataset.meta.features
    assert features["observation.state"]["names"] == [f"position.j{i}" for i in range(1, 7)]
    assert features["observation.state.joint_position"]["shape"] == (5,)
    assert features["observation.state.gripper_position"]["shape"] == (1,)
    assert dataset.meta.total_frames > 10
    for k in range(dataset.meta.total_frames):
        item = dataset[k]
        split = np.concatenate(
            [
                item["observation.state.joint_position"].numpy(),
                item["observation.state.gripper_position"].numpy().reshape(1),
            ]
        )
        np.testing.assert_array_equal(item["observation.state"].numpy(), split)
