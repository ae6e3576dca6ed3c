"""Rosetta compatibility: its README's contract examples load unchanged, and the DROID pattern
(split sub-keys next to the combined state) converts to consistent columns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bagport.config import ConvertConfig
from bagport.contract import FeatureKind, parse_contract
from bagport.episode import convert_episode
from bagport.run import plan_run, reduce_run
from bagport.synth import EpisodeSpec, write_episode_bag

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
    return np.asarray(msg.data, dtype=np.float64)


def encode_my_command(values, spec):
    return None
"""


def test_rosetta_readme_contract_loads_unchanged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    package = tmp_path / "my_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "converters.py").write_text(CONVERTERS)
    monkeypatch.syspath_prepend(str(tmp_path))  # how a worker finds a local decoder: on its path
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
    reduce_run(plan, [convert_episode(r).dir_uri for r in plan.requests])
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
