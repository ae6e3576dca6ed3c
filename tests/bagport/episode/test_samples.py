"""Publishers with different joints on one JointState topic (an arm's and a gripper's driver on
/joint_states, as robot_state_publisher accepts them): an entry naming joints reads only the messages
naming all of them, in pass 1, pass 2 and the contract check, in every storage format."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from bagport.bags import open_bag
from bagport.contract import ContractPlan, parse_contract
from bagport.episode.checks import check_window_has_data
from bagport.episode.timeline import scan_plan_timeline
from bagport.errors import AlignmentError, ContractError
from bagport.feature_table import describe_features
from tests.bagport.decode.bagwriter import write_bag
from tests.helpers import convert_in_process

TS = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)  # a ROS 1 header has a seq before its stamp
FPS = 10
FRAMES = 12
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 1_000_000_000 // FPS
GRIPPER_LAG_NS = 30_000_000
JOINT_STATE = "sensor_msgs/msg/JointState"


def _joint_state(store: Typestore, t_ns: int, names: list[str], positions: list[float]) -> Any:
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    header = types["std_msgs/msg/Header"]
    return types[JOINT_STATE](
        header=header(seq=0, stamp=stamp, frame_id="") if store is TS1 else header(stamp=stamp, frame_id=""),
        name=names,
        position=np.array(positions, dtype=np.float64),
        velocity=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
    )


def write_shared_joint_states(path: Path, storage: Literal["mcap", "sqlite3", "ros1"]) -> Path:
    """The arm (j1, j2: k, -k) at the ticks, the gripper (g: 100 + k) 30 ms after each, on one topic."""
    store = TS1 if storage == "ros1" else TS
    messages = []
    for k in range(FRAMES):
        t_ns = START_NS + k * PERIOD_NS
        messages.append((t_ns, _joint_state(store, t_ns, ["j1", "j2"], [k, -k])))
        gripper_ns = t_ns + GRIPPER_LAG_NS
        messages.append((gripper_ns, _joint_state(store, gripper_ns, ["g"], [100.0 + k])))
    return write_bag(path, storage, store, [("/joint_states", JOINT_STATE, messages)])


def _entry(key: str, names: str, stamp: str = "header") -> str:
    return (
        f"  - key: {key}\n    topic: /joint_states\n    type: {JOINT_STATE}\n    dtype: float64\n"
        f"    selector: {{names: {names}}}\n    align: {{strategy: hold, stamp: {stamp}}}\n"
    )


def _contract(stamp: str = "header") -> str:
    return (
        f"robot_type: two_drivers\nfps: {FPS}\ndefault_task: hold the cube\nobservations:\n"
        + _entry("observation.state", "[position.j1, j2]", stamp)
        + _entry("observation.state", "[g]", stamp)
        + _entry("observation.elbow", "[j2]", stamp)
    )


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_each_entry_reads_the_messages_naming_its_joints(
    tmp_path: Path, storage: Literal["mcap", "sqlite3", "ros1"]
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = write_shared_joint_states(tmp_path / "shared", storage)
    stamp = "publish" if storage == "mcap" else "header"
    rows = {row.key: row for row in describe_features(parse_contract(_contract(stamp), "c.yaml"), str(bag))}
    assert rows["observation.state"].names == ("position.j1", "j2", "g")
    out = convert_in_process(str(bag), _contract(stamp), tmp_path)
    dataset = LeRobotDataset("test/shared", root=out)
    # the grid runs from the first gripper message (30 ms after the arm's) to the arm's last message
    frames = FRAMES - 1
    assert dataset.meta.total_frames == frames
    state = np.stack([dataset[k]["observation.state"].numpy() for k in range(frames)])
    elbow = np.stack([dataset[k]["observation.elbow"].numpy().reshape(-1) for k in range(frames)])
    expected = np.array([[k, -k, 100.0 + k] for k in range(frames)])
    np.testing.assert_array_equal(state, expected)
    np.testing.assert_array_equal(elbow[:, 0], expected[:, 1])


def test_the_streams_are_named_by_their_joints_only_when_entries_differ(tmp_path: Path) -> None:
    bag = write_shared_joint_states(tmp_path / "shared", "mcap")
    plan = parse_contract(_contract(), "c.yaml")
    assert plan.streams() == ("/joint_states#j1,j2", "/joint_states#g", "/joint_states#j2")
    with open_bag(str(bag)) as reader:
        timeline = scan_plan_timeline(reader, plan)
    arm, gripper = timeline.topics["/joint_states#j1,j2"], timeline.topics["/joint_states#g"]
    ticks = START_NS + PERIOD_NS * np.arange(FRAMES)
    np.testing.assert_array_equal(arm.log_ns, ticks)
    np.testing.assert_array_equal(gripper.log_ns, ticks + GRIPPER_LAG_NS)
    assert gripper.header_ns is not None
    np.testing.assert_array_equal(gripper.header_ns, ticks + GRIPPER_LAG_NS)
    assert (arm.passed_over, gripper.passed_over) == (FRAMES, FRAMES)  # pass 2 asks again: the other's
    alone = parse_contract(
        f"robot_type: r\nfps: {FPS}\nobservations:\n" + _entry("observation.state", "[j1]"), "c"
    )
    assert alone.streams() == ("/joint_states",)  # one selection on the topic: its name stays the topic's


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_an_entry_whose_joints_no_message_names_together_says_to_split_it(
    tmp_path: Path, storage: Literal["mcap", "ros1"]
) -> None:
    bag = write_shared_joint_states(tmp_path / "shared", storage)
    text = f"robot_type: r\nfps: {FPS}\nobservations:\n" + _entry("observation.state", "[j1, g]")
    checked, converted = _refused(parse_contract(text, "c.yaml"), bag)
    said = str(checked)
    assert "no message on /joint_states" in said
    assert "carries all of the joints ['j1', 'g'] (joint lists seen: ['j1', 'j2'], ['g'])" in said
    assert checked.field == "observations[key=observation.state].selector.names"
    assert "give each publisher's joints their own entry with the same key" in said
    assert "joint lists seen: ['j1', 'j2']" in str(converted)


def _refused(plan: ContractPlan, bag: Path) -> tuple[ContractError, AlignmentError]:
    """What contract check and convert's pass 1 say of ``plan`` on ``bag``: both refuse it."""
    with pytest.raises(ContractError) as checked:
        describe_features(plan, str(bag))
    with open_bag(str(bag)) as reader, pytest.raises(AlignmentError) as converted:
        scan_plan_timeline(reader, plan)
    return checked.value, converted.value


def mean_and_max(msg: Any, _spec: Any) -> list[float]:
    """A decoder registered for JointState: its values are its own, selector.names only label them."""
    return [float(np.mean(msg.position)), float(np.max(msg.position))]


def test_a_decoder_registered_for_joint_state_reads_every_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bagport.decode import custom, register_decoder  # noqa: PLC0415

    monkeypatch.setattr(custom, "_REGISTRY", dict(custom._REGISTRY))
    register_decoder(JOINT_STATE)(mean_and_max)
    bag = write_shared_joint_states(tmp_path / "shared", "mcap")
    plan = parse_contract(
        f"robot_type: r\nfps: {FPS}\nobservations:\n" + _entry("observation.summary", "[mean, max]"), "c.yaml"
    )
    assert plan.stream_filters() == {}  # the names are labels, not joints a message must name
    rows = describe_features(plan, str(bag))
    assert rows[0].names == ("mean", "max")


def test_a_window_without_the_topic_says_so_not_that_the_joints_are_wrong(tmp_path: Path) -> None:
    """An episode window where the shared topic has no message at all: the window's check names it (a
    filtered stream with no sample in it is only the joints' fault when the topic had other messages)."""
    bag = write_shared_joint_states(tmp_path / "shared", "mcap")
    plan = parse_contract(
        f"robot_type: r\nfps: {FPS}\nobservations:\n" + _entry("observation.state", "[j1]"), "c"
    )
    window = (START_NS + FRAMES * PERIOD_NS, START_NS + (FRAMES + 5) * PERIOD_NS)  # after the last message
    with open_bag(str(bag)) as reader:
        timeline = scan_plan_timeline(reader, plan, window)
        with pytest.raises(
            AlignmentError, match=r"topic /joint_states has no messages in the episode window"
        ):
            check_window_has_data(timeline, window, reader.info.start_ns, str(bag))


def test_entries_selecting_the_same_joints_in_another_order_share_a_stream() -> None:
    text = (
        f"robot_type: r\nfps: {FPS}\nobservations:\n"
        + _entry("observation.a", "[j1, j2]")
        + _entry("observation.b", "[velocity.j2, j1]")
        + _entry("observation.c", "[g]")
        + _entry("observation.d", "['a,b']")
    )
    plan = parse_contract(text, "c.yaml")
    assert plan.streams() == ("/joint_states#j1,j2", "/joint_states#g", '/joint_states#"a,b"')


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_an_entry_selecting_by_index_on_a_shared_topic_is_refused_not_mixed(
    tmp_path: Path, storage: Literal["mcap", "ros1"]
) -> None:
    """`position[0]` reads every message: on a topic two publishers share it would take the arm's j1 and the
    gripper's g in turn, without a sign. contract check and convert refuse it and say to select by name."""
    bag = write_shared_joint_states(tmp_path / "shared", storage)
    text = f"robot_type: r\nfps: {FPS}\nobservations:\n" + _entry("observation.state", "['position[0]']")
    plan = parse_contract(text, "c.yaml")
    assert list(plan.one_joint_list_topics()) == ["/joint_states"]
    checked, converted = _refused(plan, bag)
    said = str(checked)
    assert "/joint_states carries messages naming different joints (['j1', 'j2'], then ['g'])" in said
    assert checked.field == "observations[key=observation.state].selector.names"
    assert "select the joints by name in selector.names" in said
    assert "observations[key=observation.state]) selects by index" in str(converted)
    named = parse_contract(text.replace("['position[0]']", "['position[0]', j1]"), "c.yaml")
    assert named.one_joint_list_topics() == {}  # a joint named: the entry reads the messages naming it


COLOURS = ((200, 40, 10), (30, 220, 90), (5, 60, 250), (120, 130, 140))


def _camera_bag(path: Path, storage: Literal["mcap", "ros1"], empty: set[int]) -> Path:
    """A raw rgb8 camera at FPS, message k one solid colour, the messages in ``empty`` 0x0 (no pixels)."""
    store = TS1 if storage == "ros1" else TS
    types = store.types
    messages = []
    for k in range(FRAMES):
        t_ns = START_NS + k * PERIOD_NS
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        header = types["std_msgs/msg/Header"]
        pixels = (
            np.zeros((0,), np.uint8) if k in empty else np.tile(np.array(COLOURS[k % 4], np.uint8), 32 * 48)
        )
        side = (0, 0) if k in empty else (32, 48)
        image = types["sensor_msgs/msg/Image"](
            header=header(seq=0, stamp=stamp, frame_id="cam") if store is TS1 else header(stamp=stamp, frame_id="cam"),
            height=side[0], width=side[1], encoding="rgb8", is_bigendian=0, step=side[1] * 3, data=pixels,
        )  # fmt: skip
        messages.append((t_ns, image))
    return write_bag(path, storage, store, [("/cam", "sensor_msgs/msg/Image", messages)])


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_empty_images_are_no_frames_the_previous_one_holds(
    tmp_path: Path, storage: Literal["mcap", "ros1"]
) -> None:
    """Camera drivers publish 0x0 images before their first frame or after a glitch: they are not samples, so
    the grid starts at the first image with pixels and a frame at an empty one holds the one before."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = _camera_bag(tmp_path / "cam", storage, empty={0, 1, 6})
    text = (
        f"robot_type: r\nfps: {FPS}\ndefault_task: look\nobservations:\n"
        "  - {key: observation.images.cam, topic: /cam, type: sensor_msgs/msg/Image}\n"
    )
    plan = parse_contract(text, "c.yaml")
    with open_bag(str(bag)) as reader:
        assert scan_plan_timeline(reader, plan).topics["/cam"].passed_over == 3
    assert describe_features(plan, str(bag))[0].shape == (32, 48, 3)  # the first image with pixels
    out = convert_in_process(str(bag), text, tmp_path)
    dataset = LeRobotDataset("test/cam", root=out, video_backend="pyav")
    shown = [
        dataset[k]["observation.images.cam"].numpy().mean(axis=(1, 2)) * 255 for k in range(len(dataset))
    ]
    written = [COLOURS[k % 4] for k in range(2, FRAMES)]  # frame 0 at message 2
    written[6 - 2] = COLOURS[5 % 4]  # message 6 is empty: message 5's frame holds
    assert len(shown) == len(written)
    for k, (got, want) in enumerate(zip(shown, written, strict=True)):
        assert np.abs(got - np.array(want)).max() < 10, (k, got, want)


def test_a_camera_of_empty_images_only_is_refused(tmp_path: Path) -> None:
    bag = _camera_bag(tmp_path / "cam", "mcap", empty=set(range(FRAMES)))
    plan = parse_contract(
        f"robot_type: r\nfps: {FPS}\nobservations:\n  - {{key: observation.images.cam, topic: /cam, "
        "type: sensor_msgs/msg/Image}\n",
        "c.yaml",
    )
    checked, converted = _refused(plan, bag)
    assert f"carries an image with pixels ({FRAMES} empty image(s))" in str(checked)
    assert "the camera published no frame" in str(converted)


def test_empty_compressed_images_are_no_samples(tmp_path: Path) -> None:
    """A CompressedImage of no bytes (a driver before its first frame) is passed over as a 0x0 Image is."""
    store, types = TS, TS.types
    messages = []
    for k in range(FRAMES):
        t_ns = START_NS + k * PERIOD_NS
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        payload = b"" if k in (0, 4) else b"\xff\xd8 stands for a JPEG"
        image = types["sensor_msgs/msg/CompressedImage"](
            header=types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam"),
            format="jpeg",
            data=np.frombuffer(payload, dtype=np.uint8),
        )
        messages.append((t_ns, image))
    bag = write_bag(tmp_path / "cam", "mcap", store, [("/cam", "sensor_msgs/msg/CompressedImage", messages)])
    plan = parse_contract(
        f"robot_type: r\nfps: {FPS}\nobservations:\n  - {{key: observation.images.cam, topic: /cam, "
        "type: sensor_msgs/msg/CompressedImage}\n",
        "c.yaml",
    )
    with open_bag(str(bag)) as reader:
        cam = scan_plan_timeline(reader, plan).topics["/cam"]
    assert cam.passed_over == 2
    np.testing.assert_array_equal(
        cam.log_ns, [START_NS + k * PERIOD_NS for k in range(FRAMES) if k not in (0, 4)]
    )
