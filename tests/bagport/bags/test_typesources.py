"""Custom message types without ROS: embedded definitions (MCAP ros2msg / ros2idl, ROS 1 connection
headers) and a --msg-path folder of .msg files for bags that embed none."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bagport.bags import open_bag, read_msg_path
from bagport.bags.typesources import parse_msg_definitions
from bagport.config import ConvertConfig
from bagport.contract import parse_contract
from bagport.episode import convert_episode
from bagport.errors import BagReadError
from bagport.feature_table import describe_features
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.staging import read_summary
from flows.cli import main
from tests.bagport.decode.bagwriter import write_bag
from tests.helpers import python_output

GRIPPER = "acme_msgs/msg/Gripper"
GRIPPER_MSG = "std_msgs/Header header\nfloat64[3] gain\nint32 mode\ngeometry_msgs/Vector3 tip\n"
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
FRAMES = 8

CONTRACT = f"""\
robot_type: acme
fps: 10
observations:
  - key: observation.gripper
    topic: /gripper
    type: {GRIPPER}
    dtype: float64
    selector: {{names: ['gain[1]', mode, tip.z]}}
  - key: observation.level
    topic: /level
    type: std_msgs/msg/Float64
    dtype: float64
"""
LEVEL_ONLY = """\
robot_type: acme
fps: 10
observations:
  - {key: observation.level, topic: /level, type: std_msgs/msg/Float64, dtype: float64}
"""


def _store(ros1: bool = False) -> Any:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(GRIPPER_MSG, GRIPPER))
    return store


def _messages(store: Any, ros1: bool = False) -> list[tuple[str, str, list[tuple[int, Any]]]]:
    t = store.types
    grip, level = [], []
    for k in range(FRAMES):
        t_ns = START_NS + k * PERIOD_NS
        stamp = t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        header = t["std_msgs/msg/Header"](**({"seq": k} if ros1 else {}), stamp=stamp, frame_id="grip")
        tip = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=-k / 8)
        msg = t[GRIPPER](header=header, gain=np.array([k, 10.0 + k, 0.5]), mode=k % 3, tip=tip)
        grip.append((t_ns, msg))
        level.append((t_ns, t["std_msgs/msg/Float64"](data=k * 1.5)))
    return [("/gripper", GRIPPER, grip), ("/level", "std_msgs/msg/Float64", level)]


def _expected() -> list[list[float]]:
    return [[10.0 + k, k % 3, -k / 8] for k in range(FRAMES)]


@pytest.fixture
def bare_sqlite(tmp_path: Path) -> Path:
    """A rosbag2 SQLite bag that embeds no definition of the custom type (as Humble records them)."""
    store = _store()
    bag = write_bag(tmp_path / "bare", "sqlite3", store, _messages(store))
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions WHERE topic_type = ?", (GRIPPER,))
    return bag


@pytest.fixture
def msg_path(tmp_path: Path) -> Path:
    folder = tmp_path / "msgs" / "acme_msgs" / "msg"
    folder.mkdir(parents=True)
    (folder / "Gripper.msg").write_text(GRIPPER_MSG)
    return tmp_path / "msgs"


def test_the_type_store_has_no_such_type() -> None:
    for store in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.ROS1_NOETIC, Stores.LATEST):
        assert GRIPPER not in get_typestore(store).types


def test_undefined_type_fails_only_when_the_contract_reads_it(bare_sqlite: Path) -> None:
    with open_bag(str(bare_sqlite)) as reader:
        assert reader.undefined_types == {"/gripper": GRIPPER}
        assert len(list(reader.messages(["/level"]))) == FRAMES  # unused unknown types are skipped
        with pytest.raises(
            BagReadError,
            match=r"topic /gripper has type acme_msgs/msg/Gripper: the bag does not embed its definition.*"
            r"three ways: \(1\) pass --msg-path DIR with DIR/acme_msgs/msg/Gripper\.msg.*\(2\) record.*"
            r"\(3\) remove the topic",
        ):
            list(reader.messages(["/gripper", "/level"]))
    rows = describe_features(parse_contract(LEVEL_ONLY, "c.yaml"), str(bare_sqlite))
    assert [row.key for row in rows] == ["observation.level"]
    with pytest.raises(BagReadError, match=r"\[topic=/gripper\]"):
        describe_features(parse_contract(CONTRACT, "c.yaml"), str(bare_sqlite))


def test_msg_path_defines_it_for_inspect_check_and_convert(
    bare_sqlite: Path, msg_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    assert read_msg_path(str(msg_path)) == {GRIPPER: GRIPPER_MSG}
    assert main(["inspect", str(bare_sqlite)]) == 0
    assert "type defined nowhere: /gripper (acme_msgs/msg/Gripper)" in capsys.readouterr().out
    assert main(["inspect", str(bare_sqlite), "--msg-path", str(msg_path)]) == 0
    assert "defined nowhere" not in capsys.readouterr().out
    contract = tmp_path / "c.yaml"
    contract.write_text(CONTRACT)
    args = ["contract", "check", str(contract), "--bag", str(bare_sqlite), "--msg-path", str(msg_path)]
    assert main(args) == 0
    assert "names: gain[1], mode, tip.z" in capsys.readouterr().out
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text(f"bags:\n  - {{uri: {bare_sqlite}, task: grip}}\n")
    config = ConvertConfig(
        manifest=str(manifest),
        contract=str(contract),
        output=str(tmp_path / "ds"),
        msg_path=str(msg_path),
        on_qa_fail="keep",
    )
    plan = plan_run(config)
    assert plan.requests[0].msg_definitions == {GRIPPER: GRIPPER_MSG}  # the workers get the text
    reduce_run(plan, stage_all(plan))
    dataset = LeRobotDataset("test/acme", root=tmp_path / "ds")
    got = np.stack([dataset[k]["observation.gripper"].numpy() for k in range(FRAMES)])
    np.testing.assert_array_equal(got, _expected())
    assert dataset.meta.features["observation.gripper"]["names"] == ["gain[1]", "mode", "tip.z"]


def test_changed_msg_definitions_reconvert_and_unchanged_ones_reuse(
    bare_sqlite: Path, msg_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    contract = tmp_path / "c.yaml"
    contract.write_text(CONTRACT)
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text(f"bags:\n  - {{uri: {bare_sqlite}, task: grip}}\n")
    config = ConvertConfig(
        manifest=str(manifest), contract=str(contract), output=str(tmp_path / "ds"), msg_path=str(msg_path)
    )
    first = convert_episode(plan_run(config).requests[0])
    # the same definitions, and a QA policy applied only when the dataset is written: reused, not read
    rerun = config.model_copy(update={"on_qa_fail": "keep", "keep_failed": True})
    assert (len(plan_run(rerun).requests), len(plan_run(rerun).reused)) == (0, 1)  # the plan finds it staged
    again = plan_run(rerun, reuse=False).requests[0]  # and so does the worker, asked to convert it
    assert again.episode_id == first.episode_id
    with monkeypatch.context() as patched:
        patched.setattr("bagport.episode.convert.open_bag", _must_not_open)
        assert convert_episode(again) == first
    # a changed definition decodes differently: a new staged episode, converted from the bag
    (msg_path / "acme_msgs" / "msg" / "Gripper.msg").write_text(
        GRIPPER_MSG.replace("int32 mode", "uint32 mode")
    )
    changed = plan_run(config).requests[0]
    assert changed.episode_id != first.episode_id
    converted = convert_episode(changed)
    assert converted.dir_uri != first.dir_uri
    assert read_summary(converted.dir_uri) == converted


def _must_not_open(*args: object, **kwargs: object) -> None:
    raise AssertionError("an unchanged episode was converted again")


def _check_reads_gripper(bag: Path) -> None:
    rows = describe_features(parse_contract(CONTRACT, "c.yaml"), str(bag))
    assert rows[0].names == ("gain[1]", "mode", "tip.z")
    with open_bag(str(bag)) as reader:
        assert reader.undefined_types == {}
        msgs = [m.msg() for m in reader.messages(["/gripper"])]
    assert [[float(m.gain[1]), m.mode, m.tip.z] for m in msgs] == _expected()


def test_mcap_schema_sqlite_definitions_and_ros1_headers_need_nothing_else(tmp_path: Path) -> None:
    store = _store()
    _check_reads_gripper(write_bag(tmp_path / "msg", "mcap", store, _messages(store)))
    _check_reads_gripper(write_bag(tmp_path / "db", "sqlite3", store, _messages(store)))  # Iron+ table
    store1 = _store(ros1=True)
    _check_reads_gripper(write_bag(tmp_path / "one", "ros1", store1, _messages(store1, ros1=True)))


LEVEL_IDL = """\
================================================================================
IDL: acme_msgs/msg/Level
module acme_msgs {
  module msg {
    struct Level {
      double height;
      int32 counts[2];
    };
  };
};
"""


def test_mcap_ros2idl_schema(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    from rosbags.typesys import get_types_from_idl  # noqa: PLC0415

    store.register(get_types_from_idl(LEVEL_IDL.split("\n", 2)[2]))
    level = store.types["acme_msgs/msg/Level"]
    path = tmp_path / "idl"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(
            "/level", "acme_msgs/msg/Level", msgdef=LEVEL_IDL, rihs01=store.hash_rihs01("acme_msgs/msg/Level")
        )
        for k in range(3):
            msg = level(height=k / 2, counts=np.array([k, -k], np.int32))
            writer.write(conn, START_NS + k * PERIOD_NS, store.serialize_cdr(msg, "acme_msgs/msg/Level"))
    text = "robot_type: r\nfps: 10\nobservations:\n  - {key: s, topic: /level, type: acme_msgs/msg/Level, selector: {names: [height, 'counts[1]']}}\n"
    rows = describe_features(parse_contract(text, "c.yaml"), str(path))
    assert rows[0].shape == (2,)
    with open_bag(str(path)) as reader:
        assert [(m.msg().height, int(m.msg().counts[1])) for m in reader.messages()] == [
            (0.0, 0),
            (0.5, -1),
            (1.0, -2),
        ]


def test_msg_path_errors(tmp_path: Path) -> None:
    with pytest.raises(BagReadError, match=r"holds no \.msg files.*<package>/msg/<Type>\.msg"):
        read_msg_path(str(tmp_path))
    (tmp_path / "Loose.msg").write_text("int32 x\n")
    with pytest.raises(BagReadError, match=r"Loose\.msg: is not inside a package folder"):
        read_msg_path(str(tmp_path))
    (tmp_path / "Loose.msg").unlink()
    bad = tmp_path / "acme_msgs" / "msg"
    bad.mkdir(parents=True)
    (bad / "Broken.msg").write_text("int32[ x\n")
    with pytest.raises(BagReadError, match=r"definition of acme_msgs/msg/Broken cannot be parsed") as err:
        read_msg_path(str(tmp_path))  # parsed when read: once at the plan, not once per bag
    assert err.value.uri == f"{tmp_path}/acme_msgs/msg/Broken.msg"  # the file, not "--msg-path"
    with pytest.raises(BagReadError, match=r"definition of acme_msgs/msg/Broken cannot be parsed"):
        parse_msg_definitions({"acme_msgs/msg/Broken": "int32[ x\n"})
    (bad / "Broken.msg").write_bytes(b"int32 x # caf\xe9\n")
    with pytest.raises(
        BagReadError, match=r"Broken\.msg: is not UTF-8 text \(the byte at offset 13 is not\).*iconv"
    ):
        read_msg_path(str(tmp_path))


_PREPARED_PROBE = """
import sys
from bagport.bags import prepare_reading
stores = ("rosbags.typesys.stores.ros2_humble", "rosbags.typesys.stores.ros1_noetic")
print(*(name in sys.modules for name in stores))
prepare_reading()
print(*(name in sys.modules for name in stores))
"""


def test_prepare_reading_builds_what_a_first_bag_open_needs(tmp_path: Path) -> None:
    """What the pool's forkserver does before forking its workers: rosbags' type stores imported (a
    fresh interpreter, so nothing else has imported them)."""
    assert python_output(_PREPARED_PROBE, tmp_path / "home") == ["False", "False", "True", "True"]


@pytest.mark.parametrize("second_bag", [False, True])
def test_a_bag_without_definitions_blames_the_bundled_one_not_the_bag(
    tmp_path: Path, second_bag: bool
) -> None:
    """A Humble SQLite bag embeds no definitions: a message whose bytes do not fit is read with bagport's
    bundled definition, and the error says so (also for a second bag in the same process, whose type store
    is shared with an earlier bag's and completed from the bundled one)."""
    from bagport.errors import DecodeError  # noqa: PLC0415 - this test's own

    store = get_typestore(Stores.ROS2_HUMBLE)
    level = [(START_NS + k * PERIOD_NS, store.types["std_msgs/msg/Float64"](data=k * 1.5)) for k in range(3)]
    bag = write_bag(tmp_path / "plain", "sqlite3", store, [("/level", "std_msgs/msg/Float64", level)])
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
        con.execute("UPDATE messages SET data = substr(data, 1, 6) WHERE id = 2")  # cut short
    if second_bag:
        with open_bag(str(bag)) as first:
            assert first.info.message_count == 3
    with open_bag(str(bag)) as reader, pytest.raises(DecodeError) as caught:
        for message in reader.messages():
            message.msg()
    text = str(caught.value)
    assert "does not match bagport's bundled" in text
    assert "embedded in the bag" not in text


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_a_data_file_of_a_bag_compressed_message_by_message_says_to_give_its_folder(
    tmp_path: Path, plugin: StoragePlugin
) -> None:
    """rosbag2's compression_mode message: each message is a zstd frame, which only metadata.yaml says. The
    folder reads; its data file alone was called damaged ("copy the bag again")."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    level = "std_msgs/msg/Float64"
    folder = tmp_path / "rec"
    writer = Writer(folder, version=9, storage_plugin=plugin)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connection = writer.add_connection("/level", level, typestore=store)
        writer.write(connection, 10**9, store.serialize_cdr(store.types[level](data=1.5), level))
    with open_bag(str(folder)) as reader:
        assert [m.msg().data for m in reader.messages(("/level",))] == [1.5]
    data_file = next(p for p in folder.iterdir() if p.name != "metadata.yaml")
    with open_bag(str(data_file)) as reader, pytest.raises(BagReadError) as caught:
        [m.msg() for m in reader.messages(("/level",))]
    assert f"a message of type {level} is zstd-compressed on its own" in str(caught.value)
    assert "give the bag's folder (its metadata.yaml beside the data files)" in caught.value.fix
