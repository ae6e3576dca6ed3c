"""`bagport contract init`: a draft that parses, maps cameras, state, actions and tasks, and lists the rest."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.bags import open_bag
from bagport.contract import FeatureKind, parse_contract
from bagport.contract.draft import draft_contract, draft_contract_from_bag
from bagport.feature_table import describe_features
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.cli import main
from tests.helpers import realbag


def test_draft_from_a_teleop_bag_parses_and_maps_every_stream(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "ep", "sqlite3", EpisodeSpec(duration_s=0.3))
    with open_bag(str(tmp_path / "ep")) as reader:
        text = draft_contract(reader.info, robot_type="arm", fps=15)
    plan = parse_contract(text, "draft.yaml")
    kinds = {f.key: f.kind for f in plan.features}
    assert kinds == {
        "observation.images.front": FeatureKind.VIDEO,
        "observation.images.wrist": FeatureKind.VIDEO,
        "observation.state": FeatureKind.VECTOR,
        "action": FeatureKind.VECTOR,
    }
    assert plan.fps == 15
    assert [t.topic for t in plan.task_topics] == ["/task_prompt"]


def test_draft_lists_what_it_did_not_map_and_cli_refuses_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = realbag("rosbagjs_turtlesim/example.bag")
    out = tmp_path / "turtle.yaml"
    assert main(["contract", "init", "--bag", str(bag), "--out", str(out)]) == 0
    text = out.read_text()
    assert "#   /turtle1/pose (turtlesim/msg/Pose)" in text
    assert "topic: /turtle1/cmd_vel" in text
    parse_contract(text, str(out))
    assert main(["contract", "init", "--bag", str(bag), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_draft_maps_trajectory_commands_and_explains_tf(tmp_path: Path) -> None:
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    from tests.bagport.decode.bagwriter import write_bag  # noqa: PLC0415

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    traj = t["trajectory_msgs/msg/JointTrajectory"](
        header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=""), joint_names=["a"], points=[]
    )
    tf = t["tf2_msgs/msg/TFMessage"](transforms=[])
    bag = write_bag(
        tmp_path / "arm",
        "mcap",
        store,
        [
            ("/arm_controller/joint_trajectory", "trajectory_msgs/msg/JointTrajectory", [(10**9, traj)]),
            ("/tf", "tf2_msgs/msg/TFMessage", [(10**9, tf)]),
        ],
    )
    with open_bag(str(bag)) as reader:
        text = draft_contract(reader.info)
    assert "      topic: /arm_controller/joint_trajectory" in text
    assert "#   /tf (tf2_msgs/msg/TFMessage): map one transform with selector: {child_frame: <frame>}" in text
    assert [f.key for f in parse_contract(text, "draft.yaml").features] == ["action"]


def test_draft_maps_video_streams_and_rvl_depth_to_cameras(tmp_path: Path) -> None:
    cameras = (
        CameraSpec("front", "video", bframes=2),
        CameraSpec("wrist", "ffmpeg"),
        CameraSpec("depth", "compressed_depth", "16UC1", depth_codec="rvl"),
    )
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.5, cameras=cameras))
    with open_bag(str(tmp_path / "ep")) as reader:
        text = draft_contract(reader.info)
    plan = parse_contract(text, "draft.yaml")
    sources = {f.key: f.sources[0] for f in plan.features if f.kind is FeatureKind.VIDEO}
    assert {key: (s.topic, s.msgtype) for key, s in sources.items()} == {
        f"observation.images.{cam.name}": (cam.topic, cam.msgtype) for cam in cameras
    }
    # `contract check`: a video packet is no picture on its own, so its size is left to the conversion
    shapes = {row.key: row.shape for row in describe_features(plan, str(tmp_path / "ep"))}
    assert shapes["observation.images.front"] is None and shapes["observation.images.wrist"] is None
    assert shapes["observation.images.depth"] == (96, 128, 1)


def test_draft_names_each_publishers_joints_on_a_shared_topic(tmp_path: Path) -> None:
    """An arm's and a gripper's driver on /joint_states: the draft has an entry per joint list, with the
    same key, and it checks against the bag (an entry naming joints reads the messages naming them)."""
    from tests.bagport.episode.test_samples import write_shared_joint_states  # noqa: PLC0415

    bag = write_shared_joint_states(tmp_path / "shared", "mcap")
    with open_bag(str(bag)) as reader:
        text = draft_contract_from_bag(reader)
    assert "  # /joint_states carries 2 joint lists (publishers sharing it): an entry each, same key" in text
    assert 'selector: {names: ["position.j1", "position.j2"]}' in text
    assert 'selector: {names: ["position.g"]}' in text
    plan = parse_contract(text, "draft.yaml")
    rows = {row.key: row for row in describe_features(plan, str(bag))}
    assert rows["observation.state"].names == ("position.j1", "position.j2", "position.g")
