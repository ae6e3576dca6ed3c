"""Names as real recorders write them: ROS 1 relative topics, ROS1-style type names inside rosbag2 MCAP,
and rosbag2 folders whose metadata.yaml records other QoS than the storage file (rosbag2's `talker` bags)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags import open_bag
from bagport.contract import parse_contract
from bagport.contract.draft import draft_contract
from bagport.episode.score import score_manifest
from bagport.errors import DecodeError
from bagport.feature_table import describe_features
from bagport.segment import segment_request
from tests.bagport.decode.bagwriter import write_bag
from tests.helpers import convert_in_process

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
TS1 = get_typestore(Stores.ROS1_NOETIC)
START_NS = 1_700_000_000_000_000_000
FPS = 10
FRAMES = 8
PERIOD_NS = 1_000_000_000 // FPS


def _header(store: Any, t_ns: int) -> Any:
    types = store.types
    return types["std_msgs/msg/Header"](
        **({"seq": 0} if store is TS1 else {}),
        stamp=types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
        frame_id="base",
    )


def _joints(store: Any, t_ns: int, k: int) -> Any:
    return store.types["sensor_msgs/msg/JointState"](
        header=_header(store, t_ns),
        name=["shoulder", "elbow"],
        position=np.array([0.1 * k, -0.2 * k]),
        velocity=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
    )


def _pixels(k: int) -> np.ndarray[Any, np.dtype[np.uint8]]:
    frame = np.zeros((16, 16, 3), dtype=np.uint8)
    frame[..., 0] = 40 + 20 * k
    frame[..., 1] = 200 - 10 * k
    frame[..., 2] = 90
    return frame


def _image(t_ns: int, k: int) -> Any:
    return T["sensor_msgs/msg/Image"](
        header=_header(TS, t_ns),
        height=16,
        width=16,
        encoding="rgb8",
        is_bigendian=0,
        step=48,
        data=_pixels(k).reshape(-1),
    )


def _contract(joint_topic: str, camera: str | None = None) -> str:
    lines = [
        "robot_type: wild_bot",
        f"fps: {FPS}",
        "default_task: wave",
        "observations:",
        "  - key: observation.state",
        f"    topic: {joint_topic}",
        "    type: sensor_msgs/msg/JointState",
        "    align: {strategy: hold, stamp: receive}",
    ]
    if camera:
        lines += [
            "  - key: observation.images.cam",
            f"    topic: {camera}",
            "    type: sensor_msgs/Image",
            "    align: {strategy: hold, stamp: receive}",
        ]
    return "\n".join(lines) + "\n"


def _ticks() -> list[int]:
    return [START_NS + k * PERIOD_NS for k in range(FRAMES)]


def _states(out: Path) -> np.ndarray[Any, np.dtype[np.float64]]:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    dataset = LeRobotDataset("test/wild", root=out)
    assert dataset.meta.total_frames == FRAMES
    return np.stack([dataset[k]["observation.state"].numpy() for k in range(FRAMES)])


def test_ros1_relative_topic_is_its_global_name(tmp_path: Path) -> None:
    """A ROS 1 bag recording ``joint_states`` (no leading slash): inspect, contract init, contract check,
    QA and convert all know it as ``/joint_states``, and the values are the ones written."""
    streams = [
        (
            "joint_states",
            "sensor_msgs/msg/JointState",
            [(t, _joints(TS1, t, k)) for k, t in enumerate(_ticks())],
        )
    ]
    bag = write_bag(tmp_path / "relative", "ros1", TS1, streams)
    with open_bag(str(bag)) as reader:
        assert [t.name for t in reader.info.topics] == ["/joint_states"]
        assert {m.topic for m in reader.messages(["/joint_states"])} == {"/joint_states"}
        draft = draft_contract(reader.info, robot_type="wild_bot", fps=FPS)
    assert re.search(r"topic: /joint_states\n", draft), draft
    rows = describe_features(parse_contract(_contract("/joint_states"), "c.yaml"), str(bag))
    assert rows[0].names == ("position.shoulder", "position.elbow")
    (tmp_path / "c.yaml").write_text(_contract("/joint_states"))
    (tmp_path / "m.yaml").write_text(f"bags:\n  - {{uri: {bag}, task: wave}}\n")
    (entry,) = score_manifest(str(tmp_path / "m.yaml"), str(tmp_path / "c.yaml"), workers=1)
    assert entry.qa.error is None and entry.qa.verdict != "fail", entry.qa.headline()
    out = convert_in_process(str(bag), _contract("/joint_states"), tmp_path, repo_id="test/wild")
    want = np.array([[0.1 * k, -0.2 * k] for k in range(FRAMES)], dtype=np.float32)
    np.testing.assert_allclose(_states(out), want, atol=1e-6)


def _ros1_style_mcap(path: Path) -> Path:
    """A rosbag2 MCAP whose schemas are named ``sensor_msgs/Image`` (ROS1 style) with ros2msg text."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, full in (
            ("/cam", "sensor_msgs/msg/Image"),
            ("/joint_states", "sensor_msgs/msg/JointState"),
        ):
            msgdef, _ = TS.generate_msgdef(full, ros_version=2)
            short = full.replace("/msg/", "/")
            conns[topic] = writer.add_connection(topic, short, msgdef=msgdef, rihs01=TS.hash_rihs01(full))
        for k, t in enumerate(_ticks()):
            writer.write(
                conns["/joint_states"], t, TS.serialize_cdr(_joints(TS, t, k), "sensor_msgs/msg/JointState")
            )
            writer.write(conns["/cam"], t, TS.serialize_cdr(_image(t, k), "sensor_msgs/msg/Image"))
    return path


def test_ros1_style_type_names_in_mcap_are_full_names(tmp_path: Path) -> None:
    bag = _ros1_style_mcap(tmp_path / "short_types")
    with open_bag(str(bag)) as reader:
        assert {t.name: t.msgtype for t in reader.info.topics} == {
            "/cam": "sensor_msgs/msg/Image",
            "/joint_states": "sensor_msgs/msg/JointState",
        }
        assert reader.undefined_types == {}
        draft = draft_contract(reader.info, robot_type="wild_bot", fps=FPS)
    assert "key: observation.images.cam" in draft and "type: sensor_msgs/msg/Image" in draft, draft
    contract = _contract("/joint_states", camera="/cam")
    rows = {r.key: r for r in describe_features(parse_contract(contract, "c.yaml"), str(bag))}
    assert rows["observation.images.cam"].shape == (16, 16, 3)
    out = convert_in_process(str(bag), contract, tmp_path, repo_id="test/wild")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    dataset = LeRobotDataset("test/wild", root=out)
    for k in range(FRAMES):
        frame = (dataset[k]["observation.images.cam"].numpy().transpose(1, 2, 0) * 255).round()
        np.testing.assert_allclose(frame.mean(axis=(0, 1)), _pixels(k)[0, 0], atol=3)


def test_msg_path_lookup_accepts_ros1_style_names(tmp_path: Path) -> None:
    """A custom type named ``acme_msgs/Grip`` in the bag with an empty (placeholder) definition:
    the error names topic, type, the placeholder and the --msg-path file to add, and --msg-path's
    ``acme_msgs/msg/Grip.msg`` then defines it."""
    from rosbags.typesys import get_types_from_msg  # noqa: PLC0415

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg("float64 width\n", "acme_msgs/msg/Grip"))
    bag = tmp_path / "grip"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection("/grip", "acme_msgs/Grip", msgdef="", rihs01="RIHS01_" + "0" * 64)
        grip = store.types["acme_msgs/msg/Grip"](width=0.25)
        writer.write(conn, START_NS, store.serialize_cdr(grip, "acme_msgs/msg/Grip"))
    with open_bag(str(bag)) as reader:
        assert {t.name: t.msgtype for t in reader.info.topics} == {"/grip": "acme_msgs/msg/Grip"}
        with pytest.raises(DecodeError) as caught:
            [m.msg() for m in reader.messages(["/grip"])]
    assert str(caught.value) == (
        f"{bag}: a message of type acme_msgs/msg/Grip does not match the bag's empty (placeholder) "
        "definition (the bytes do not fit: CDR message size mismatch for 'acme_msgs/msg/Grip') "
        f"[topic=/grip, t_ns={START_NS}] Fix: the recorder embedded no definition of acme_msgs/msg/Grip: "
        "pass it as --msg-path DIR with DIR/acme_msgs/msg/Grip.msg (and the types it uses), or remove the "
        "topic from the contract."
    )
    with open_bag(str(bag), msg_definitions={"acme_msgs/msg/Grip": "float64 width\n"}) as reader:
        assert [m.msg().width for m in reader.messages(["/grip"])] == [0.25]


def _talker_like(path: Path, storage: StoragePlugin) -> Path:
    """What makes rosbag2's own ``talker`` bags special: their metadata.yaml (version 4) records
    ``offered_qos_profiles`` that differ from the ones the storage file records for the same topics."""
    with Writer(path, version=9, storage_plugin=storage) as writer:
        conn = writer.add_connection("/topic", "std_msgs/msg/String", typestore=TS)
        for k in range(10):
            writer.write(
                conn,
                START_NS + k * 500_000_000,
                TS.serialize_cdr(T["std_msgs/msg/String"](data=f"Hello, world! {k}"), "std_msgs/msg/String"),
            )
    metadata = path / "metadata.yaml"
    info = yaml.safe_load(metadata.read_text())
    for topic in info["rosbag2_bagfile_information"]["topics_with_message_count"]:
        topic["topic_metadata"]["offered_qos_profiles"] = (
            "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 0\n    nsec: 0\n"
            "  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n"
            "    nsec: 0\n  avoid_ros_namespace_conventions: false"
        )
    metadata.write_text(yaml.safe_dump(info))
    return path


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3], ids=["mcap", "sqlite3"])
def test_metadata_qos_unlike_the_files_still_reads_every_message(
    tmp_path: Path, storage: StoragePlugin
) -> None:
    bag = _talker_like(tmp_path / "talker", storage)
    with open_bag(str(bag)) as reader:
        got = [m.msg().data for m in reader.messages(["/topic"])]
        windowed = list(reader.messages(["/topic"], start_ns=START_NS + 1, stop_ns=START_NS + 2_000_000_000))
    assert got == [f"Hello, world! {k}" for k in range(10)]
    assert len(windowed) == 3


def test_short_read_guard_still_catches_a_real_shortfall(tmp_path: Path) -> None:
    """The QoS alignment does not hide a real truncation: metadata promising more than the file has."""
    bag = _talker_like(tmp_path / "talker", StoragePlugin.SQLITE3)
    metadata = bag / "metadata.yaml"
    info = yaml.safe_load(metadata.read_text())
    info["rosbag2_bagfile_information"]["topics_with_message_count"][0]["message_count"] = 12
    metadata.write_text(yaml.safe_dump(info))
    with (
        open_bag(str(bag)) as reader,
        pytest.raises(Exception, match="yielded 10 messages on /topic, its index promises 12"),
    ):
        list(reader.messages(["/topic"]))


def test_real_talker_bags_when_present(tmp_path: Path) -> None:
    """rosbag2's own ``talker`` test bags, if the shared real-bag folder has them."""
    from tests.helpers import REALBAGS  # noqa: PLC0415

    found = sorted(p.parent for p in REALBAGS.glob("**/talker*/metadata.yaml")) if REALBAGS.exists() else []
    if not found:
        pytest.skip("rosbag2's talker bags are not in shared/realbags; the trait is reproduced above")
    for folder in found:
        with open_bag(str(folder)) as reader:
            assert len(list(reader.messages(["/topic"]))) == 10


def test_ros1_relative_event_topic_splits_episodes(tmp_path: Path) -> None:
    from tests.helpers import episode_request  # noqa: PLC0415

    ticks = [START_NS + k * PERIOD_NS for k in range(40)]
    events = [(ticks[5], "START"), (ticks[25], "SUCCESS")]
    string = TS1.types["std_msgs/msg/String"]
    streams = [
        (
            "joint_states",
            "sensor_msgs/msg/JointState",
            [(t, _joints(TS1, t, k)) for k, t in enumerate(ticks)],
        ),
        ("episode_events", "std_msgs/msg/String", [(t, string(data=text)) for t, text in events]),
    ]
    bag = write_bag(tmp_path / "relative", "ros1", TS1, streams)
    contract = _contract("/joint_states") + "episodes:\n  events: {topic: /episode_events}\n"
    describe_features(parse_contract(contract, "c.yaml"), str(bag))  # contract check --bag passes
    found = segment_request(episode_request(bag, tmp_path / "staging", contract))
    assert [(r.window.start_ns, r.window.end_ns, r.label) for r in found.requests] == [
        (ticks[5], ticks[25], "success")
    ]
