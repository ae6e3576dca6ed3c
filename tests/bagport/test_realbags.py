"""Real bags recorded by real ROS tooling convert where a contract fits, and LeRobot loads them."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq
import pytest
import yaml

from bagport.bags import open_bag
from bagport.columns import vector_column
from bagport.config import ConvertConfig
from bagport.contract import load_contract, parse_contract
from bagport.contract.draft import draft_contract
from bagport.dataset.validate import validate_dataset
from bagport.decode.defaults import DEFAULT_FIELDS
from bagport.decode.paths import resolve_path
from bagport.errors import AlignmentError, ContractError, QualityError
from bagport.feature_table import describe_features
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.video.settings import default_encoder
from tests.helpers import REPO, realbag


def _convert(
    manifest: Path,
    contract: Path,
    out: Path,
    *,
    keep_qa_failures: bool = False,
    encoder: dict[str, Any] | None = None,
) -> None:
    config = ConvertConfig(
        manifest=str(manifest),
        contract=str(contract),
        output=str(out),
        on_qa_fail="keep" if keep_qa_failures else None,
        encoder=default_encoder() if encoder is None else encoder,
    )
    plan = plan_run(config)
    staged = stage_all(plan)
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


RERUN = "rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap"
ARRAYS = "rosbag2parquet/array_msgs"


def test_humble_joint_states(tmp_path: Path) -> None:
    bag = realbag(RERUN)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n    task: wave\n")
    out = tmp_path / "rerun"
    _convert(manifest, REPO / "configs/contracts/rerun_joint_state.yaml", out)
    validate_dataset(out, repo_id="test/rerun")
    info = json.loads((out / "meta/info.json").read_text())
    assert info["total_frames"] == 15  # 1.5 s of 10 Hz joint states on a 10 fps grid
    assert len(info["features"]["observation.state"]["names"]) == 4


@pytest.mark.parametrize("relative", [RERUN, ARRAYS])
def test_joint_states_recorded_by_ros2_read_from_their_bytes_as_rosbags_reads_them(relative: str) -> None:
    """The CDR that ROS 2's own serialiser wrote (``bagport.decode.joint_state_cdr``): every message."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415

    from bagport.decode.joint_state_cdr import JointStateCdr  # noqa: PLC0415

    reader, read = JointStateCdr(), 0
    with AnyReader([realbag(relative)]) as bag:
        conns = [c for c in bag.connections if c.msgtype == "sensor_msgs/msg/JointState"]
        for conn, _, raw in bag.messages(connections=conns):
            msg: Any = bag.deserialize(raw, conn.msgtype)
            arrays = reader.read(raw)
            assert arrays is not None and arrays.name == tuple(msg.name)
            for field in ("position", "velocity", "effort"):
                assert getattr(arrays, field).tobytes() == np.asarray(getattr(msg, field)).tobytes()
            read += 1
    assert read >= 1


def _held(stamps_ns: list[int], tick_ns: int) -> int:
    """Index of the message ``hold`` takes at a tick: the latest stamp at or before it (ties: last logged)."""
    return max((i for i, t in enumerate(stamps_ns) if t <= tick_ns), key=lambda i: (stamps_ns[i], i))


def test_stinger_boat_imu_and_tf(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy
    from rosbags.highlevel import AnyReader  # noqa: PLC0415
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    bag = realbag("stinger_localization/localization_bag")
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n")
    out = tmp_path / "stinger"
    _convert(manifest, REPO / "configs/contracts/stinger_localization.yaml", out)
    # ground truth read independently with rosbags (the bag embeds no definitions: Humble's types)
    imu_ns: list[int] = []
    imu: list[list[float]] = []
    tf_ns: list[int] = []
    tf: list[list[float]] = []
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        wanted = [c for c in reader.connections if c.topic in ("/imu/data", "/tf")]
        for connection, _, raw in reader.messages(connections=wanted):
            msg: Any = reader.deserialize(raw, connection.msgtype)
            if connection.topic == "/imu/data":
                o, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
                imu_ns.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
                imu.append([o.x, o.y, o.z, o.w, w.x, w.y, w.z, a.x, a.y, a.z])
                continue
            for transform in msg.transforms:
                if (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_link"):
                    t, r = transform.transform.translation, transform.transform.rotation
                    tf_ns.append(transform.header.stamp.sec * 10**9 + transform.header.stamp.nanosec)
                    tf.append([t.x, t.y, t.z, r.x, r.y, r.z, r.w])
    start_ns, end_ns = max(min(imu_ns), min(tf_ns)), min(max(imu_ns), max(tf_ns))
    frames = (end_ns - start_ns) * 10 // 10**9 + 1  # 10 fps grid, both ends inclusive
    dataset = LeRobotDataset("test/stinger", root=out)
    assert dataset.meta.total_frames == frames == 376
    assert dataset.meta.features["observation.pose"]["names"][0] == "base_link.translation.x"
    assert dataset[0]["task"] == "localize the boat"
    for k in (0, 1, 137, frames - 1):
        tick_ns = start_ns + k * 10**9 // 10
        item = dataset[k]
        np.testing.assert_allclose(item["observation.imu"].numpy(), imu[_held(imu_ns, tick_ns)], rtol=1e-6)
        np.testing.assert_allclose(item["observation.pose"].numpy(), tf[_held(tf_ns, tick_ns)], rtol=1e-6)
    assert len({tuple(row) for row in tf}) > 100  # the boat moves: real values, not a constant


@pytest.mark.parametrize(
    "relative",
    ["rosbag2_cdr_test_mcap/cdr_test", "rosbag2_cdr_test_sqlite3/cdr_test"],
    ids=["mcap", "sqlite3"],
)
def test_custom_test_msgs_from_embedded_definitions(tmp_path: Path, relative: str) -> None:
    """test_msgs types are defined only by the bag (MCAP schemas, SQLite's definitions table); dot paths
    with indices select into arrays and nested messages. 4 + 3 messages over 0.15 s: at 20 fps the grid
    (from the latest first message to the earliest last one, 81 ms) holds 2 frames."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    contract = tmp_path / "cdr.yaml"
    contract.write_text(
        "robot_type: rosbag2_test\nfps: 20\nobservations:\n"
        "  - key: observation.state\n    topic: /array_topic\n    type: test_msgs/msg/Arrays\n"
        "    selector: {names: ['bool_values[0]', 'float64_values_default[0]', 'int16_values_default[-1]',"
        " 'defaults_values[2].float32_value', 'uint64_values_default[1]']}\n    dtype: float64\n"
        "  - key: observation.state\n    topic: /test_topic\n    type: test_msgs/msg/BasicTypes\n"
        "    selector: {names: [int32_value]}\n    dtype: float64\n"
    )
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {realbag(relative)}\n    task: test\n")
    out = tmp_path / "cdr"
    _convert(manifest, contract, out, keep_qa_failures=True)  # QA fails a 0.05 s episode: kept, flagged
    dataset = LeRobotDataset("test/cdr", root=out)
    assert dataset.meta.total_frames == 2
    assert json.loads((out / "meta/qa/summary.json").read_text())["episodes"][0]["verdict"] == "fail"
    assert dataset.meta.features["observation.state"]["dtype"] == "float64"
    expected = [1.0, 3.1415, -32768.0, 1.125, 1.0, 123.0]  # the messages are all alike
    for k in range(2):  # LeRobot hands float64 columns out as float32 tensors
        np.testing.assert_array_equal(
            dataset[k]["observation.state"].numpy(), np.asarray(expected, dtype=np.float32)
        )
    state = vector_column(pq.read_table(out / "data/chunk-000/file-000.parquet"), "observation.state")
    np.testing.assert_array_equal(state, [expected, expected])


def test_mono8_images_from_a_folder_named_dot_bag(tmp_path: Path) -> None:
    """ros2bag_tools' 2x2 mono8 camera at 1 Hz (stamps from 0) becomes a 3-frame grey video."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    contract = tmp_path / "images.yaml"
    contract.write_text(
        "robot_type: mono_camera\nfps: 1\nobservations:\n"
        "  - {key: observation.images.mono, topic: /image, type: sensor_msgs/msg/Image}\n"
    )
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {realbag('ros2bag_tools/images.bag')}\n    task: look\n")
    out = tmp_path / "images"
    _convert(manifest, contract, out)
    dataset = LeRobotDataset("test/images", root=out)
    assert dataset.meta.total_frames == 3
    assert tuple(dataset.meta.features["observation.images.mono"]["shape"]) == (2, 2, 3)
    for k in range(3):
        image = dataset[k]["observation.images.mono"].numpy()  # (3, 2, 2) floats in [0, 1]
        grey = np.array([[0, 128], [128, 255]]) / 255  # the message's bytes 00 80 80 ff
        for channel in image:
            np.testing.assert_allclose(channel, grey, atol=6 / 255)


def test_empty_bag_is_a_clear_error(tmp_path: Path) -> None:
    bag = realbag("rosbagjs_turtlesim/no-messages.bag")
    plan = load_contract(str(REPO / "configs/contracts/turtlesim.yaml"))
    with pytest.raises(ContractError, match=r"no-messages\.bag holds no messages \(no topics\)"):
        describe_features(plan, str(bag))


@pytest.mark.parametrize("relative", ["foxglove_chatter_db3/chatter.db3", "rosbag2_split/wbag"])
def test_string_only_bags_fit_no_contract(relative: str) -> None:
    """Bags of std_msgs/String topics only carry no feature LeRobot could train on (a String is a task
    at most): `contract init` maps nothing and says so, and the draft is refused with the fix."""
    with open_bag(str(realbag(relative))) as reader:
        draft = draft_contract(reader.info)
        topics = [t.name for t in reader.info.topics]
    assert all(f"#   {topic} (std_msgs/msg/String)" in draft for topic in topics)
    with pytest.raises(ContractError, match=r"declares no features Fix: add at least one entry"):
        parse_contract(draft, "draft.yaml")


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


ARCHIVAL = yaml.safe_load((REPO / "configs/codecs/archival.yaml").read_text())
"""Near-lossless (H.264 yuv444p crf 0): decoded RGB is within 2 levels of what was encoded."""


def _only_message(bag: Path, topic: str) -> Any:
    with open_bag(str(bag)) as reader:
        (message,) = list(reader.messages([topic]))
        return message.msg()


def _one_topic_contract(tmp_path: Path, key: str, topic: str, msgtype: str) -> Path:
    contract = tmp_path / "c.yaml"
    contract.write_text(
        f"robot_type: one_shot\nfps: 10\nobservations:\n  - {{key: {key}, topic: {topic}, type: {msgtype}}}\n"
    )
    return contract


def _manifest(tmp_path: Path, bag: Path) -> Path:
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n    task: look\n")
    return manifest


@pytest.mark.parametrize(
    ("topic", "msgtype"),
    [("/image", "sensor_msgs/msg/Image"), ("/compressed_image", "sensor_msgs/msg/CompressedImage")],
    ids=["rgb8", "jpeg"],
)
def test_humble_single_camera_image_is_a_one_frame_video_of_its_pixels(
    tmp_path: Path, topic: str, msgtype: str
) -> None:
    """The bag's one Image (rgb8 640x480) and one CompressedImage (JPEG) each become the one frame of a
    dataset whose decoded pixels are the message's, in RGB order. One message spans 0 s: QA fails the
    episode by default (see test_one_message_episode_fails_qa_unless_kept), so it is kept here."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy
    from PIL import Image  # noqa: PLC0415

    bag = realbag(RERUN)
    msg = _only_message(bag, topic)
    if msgtype.endswith("/Image"):
        assert (msg.encoding, msg.width, msg.height, msg.step) == ("rgb8", 640, 480, 640 * 3)
        source: npt.NDArray[np.uint8] = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(480, 640, 3)
    else:  # decoded by PIL, not by bagport's own JPEG decoder (simplejpeg)
        assert msg.format == "jpeg"
        source = np.asarray(Image.open(io.BytesIO(bytes(msg.data))).convert("RGB"))
    out = tmp_path / "camera"
    contract = _one_topic_contract(tmp_path, "observation.images.cam", topic, msgtype)
    _convert(_manifest(tmp_path, bag), contract, out, keep_qa_failures=True, encoder=ARCHIVAL)
    dataset = LeRobotDataset("test/camera", root=out)
    assert dataset.meta.total_frames == 1
    assert tuple(dataset.meta.features["observation.images.cam"]["shape"]) == (480, 640, 3)
    frame = np.rint(dataset[0]["observation.images.cam"].numpy().transpose(1, 2, 0) * 255)
    error = np.abs(frame - source)
    assert error.max() <= 2  # the archival preset's RGB -> YUV -> RGB rounding
    # both images are uniform noise: every channel's mean is 127.5 +- 0.3, so the means alone barely
    # tell RGB from BGR; the pixels do: against the source with R and B swapped the frame is off by
    # 57 (rgb8) and 18 (jpeg) levels on average, against the source by 0.4
    assert np.abs(frame - source[..., ::-1]).mean() > 10
    np.testing.assert_allclose(frame.reshape(-1, 3).mean(0), source.reshape(-1, 3).mean(0), atol=0.1)


@pytest.mark.parametrize(
    ("topic", "msgtype", "names"),
    [
        ("/one_shot/joint_state", "sensor_msgs/msg/JointState", [f"position.joint{i}" for i in (1, 2, 3)]),
        ("/one_shot/imu", "sensor_msgs/msg/Imu", [*DEFAULT_FIELDS["sensor_msgs/msg/Imu"]]),
    ],
    ids=["joint_state", "imu"],
)
def test_one_message_stream_is_a_one_frame_dataset_when_kept(
    tmp_path: Path, topic: str, msgtype: str, names: list[str]
) -> None:
    """rosbag2parquet's array_msgs: one JointState (joint1..3) and one Imu; each alone is one frame."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = realbag(ARRAYS)
    msg = _only_message(bag, topic)
    if msgtype.endswith("/JointState"):
        assert list(msg.name) == ["joint1", "joint2", "joint3"]
        expected = [float(v) for v in msg.position]
    else:
        expected = [float(resolve_path(msg, name, topic)) for name in names]
    out = tmp_path / "one"
    contract = _one_topic_contract(tmp_path, "observation.state", topic, msgtype)
    _convert(_manifest(tmp_path, bag), contract, out, keep_qa_failures=True)
    dataset = LeRobotDataset("test/one", root=out)
    assert dataset.meta.total_frames == 1
    assert dataset.meta.features["observation.state"]["names"] == names
    np.testing.assert_allclose(dataset[0]["observation.state"].numpy(), expected, rtol=1e-6)
    verdict = json.loads((out / "meta/qa/summary.json").read_text())["episodes"][0]["verdict"]
    assert verdict == "fail"  # kept, and flagged


def test_one_message_episode_fails_qa_unless_kept(tmp_path: Path) -> None:
    bag = realbag(ARRAYS)
    contract = _one_topic_contract(
        tmp_path, "observation.state", "/one_shot/joint_state", "sensor_msgs/msg/JointState"
    )
    with pytest.raises(
        QualityError,
        match=r"(?s)no episode is left to write.*episode lasts 0\.00 s.*1 message\(s\) inside the episode window"
        r".*--on-qa-fail keep",
    ):
        _convert(_manifest(tmp_path, bag), contract, tmp_path / "out")


def test_one_shot_joint_state_and_imu_never_overlap(tmp_path: Path) -> None:
    """array_msgs logs its Imu 1.3 s before its JointState, one message each: no frame holds both."""
    bag = realbag(ARRAYS)
    contract = tmp_path / "c.yaml"
    contract.write_text(
        "robot_type: one_shot\nfps: 10\nobservations:\n"
        "  - {key: observation.state, topic: /one_shot/joint_state, type: sensor_msgs/msg/JointState}\n"
        "  - {key: observation.imu, topic: /one_shot/imu, type: sensor_msgs/msg/Imu}\n"
    )
    with pytest.raises(
        AlignmentError,
        match=r"array_msgs: the streams never overlap in time \(/one_shot/joint_state starts after "
        r"/one_shot/imu ends\).*Fix: check the topics, the stamp source",
    ):
        _convert(_manifest(tmp_path, bag), contract, tmp_path / "out")
