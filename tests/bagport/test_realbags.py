"""Real bags recorded by real ROS tooling convert where a contract fits, and LeRobot loads them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from bagport.columns import vector_column
from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.episode import convert_episode
from bagport.run import plan_run, reduce_run
from tests.helpers import REPO, realbag


def _convert(manifest: Path, contract: Path, out: Path) -> None:
    plan = plan_run(ConvertConfig(manifest=str(manifest), contract=str(contract), output=str(out)))
    staged = [convert_episode(request).dir_uri for request in plan.requests]
    reduce_run(plan, staged)


def test_ros1_turtlesim_with_custom_types(tmp_path: Path) -> None:
    realbag("rosbagjs_turtlesim/example.bag")
    out = tmp_path / "turtles"
    _convert(REPO / "manifests/realbags.yaml", REPO / "configs/contracts/turtlesim.yaml", out)
    report = validate_dataset(out, repo_id="test/turtles")
    assert report.episodes == 2
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["observation.state"]["names"] == ["x", "y", "theta"]
    assert info["video_path"] is None
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    state = vector_column(data, "observation.state")
    assert state[:, 0].min() > 0 and state[:, 0].max() < 12  # turtlesim's world is 11 x 11
    run = json.loads((out / "meta/provenance/run.json").read_text())
    assert all(
        e["stamp_sources"]
        == {"observation.state@/turtle1/pose": "receive", "action@/turtle1/cmd_vel": "receive"}
        for e in run["episodes"]
    )
    # the lz4-compressed copy of the same recording gives the same frames
    episodes = data.column("episode_index").to_numpy()
    np.testing.assert_array_equal(state[episodes == 0], state[episodes == 1])


def test_humble_joint_states(tmp_path: Path) -> None:
    bag = realbag("rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap")
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n    task: wave\n")
    out = tmp_path / "rerun"
    _convert(manifest, REPO / "configs/contracts/rerun_joint_state.yaml", out)
    validate_dataset(out, repo_id="test/rerun")
    info = json.loads((out / "meta/info.json").read_text())
    assert info["total_frames"] == 15  # 1.5 s of 10 Hz joint states on a 10 fps grid
    assert len(info["features"]["observation.state"]["names"]) == 4


def test_ros1_tf_lookup_matches_the_pose_it_was_broadcast_from(tmp_path: Path) -> None:
    """ROS 1 ``tf/tfMessage`` (the pre-tf2 type on old bags' /tf) works as a TF lookup."""
    bag = realbag("rosbagjs_turtlesim/example.bag")
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n    task: drive the turtle\n")
    contract = tmp_path / "c.yaml"
    contract.write_text(
        "robot_type: turtlesim\nfps: 30\nobservations:\n"
        "  - key: observation.state\n    topic: /turtle1/pose\n    type: turtlesim/Pose\n"
        "    selector: {names: [x, y]}\n"
        "  - key: observation.tf\n    topic: /tf\n    type: tf/tfMessage\n"
        "    selector: {child_frame: turtle1, names: [translation.x, translation.y]}\n"
    )
    out = tmp_path / "tf"
    _convert(manifest, contract, out)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["observation.tf"]["names"] == ["turtle1.translation.x", "turtle1.translation.y"]
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    pose, tf = vector_column(data, "observation.state"), vector_column(data, "observation.tf")
    # turtle_tf broadcasts world -> turtle1 from each pose, in the same instant: the two streams agree
    np.testing.assert_allclose(tf, pose, atol=1e-5)
    assert np.ptp(tf[:, 0]) > 1.0  # the turtle moves: not a constant
