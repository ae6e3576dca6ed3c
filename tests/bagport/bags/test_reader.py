"""One behavioural suite over every real bag in ../shared/realbags, plus a corruption ladder."""

from __future__ import annotations

import shutil
from pathlib import Path

import fsspec
import pytest
import zstandard

from bagport.bags import Storage, format_bag_info, open_bag
from bagport.errors import BagReadError
from bagport.scratch import scratch_dir
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import realbag

# (path under realbags, storage, messages) as the catalog lists them
CATALOG = [
    ("rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap", Storage.MCAP, 194),
    ("rosbag2parquet/array_msgs", Storage.MCAP, 2),
    ("rosbag2parquet/base_msgs", Storage.MCAP, 3),
    ("stinger_localization/localization_bag", Storage.SQLITE3, 774),
    ("ros2bag_tools/images.bag", Storage.SQLITE3, 3),
    ("rosbag2_split/wbag", Storage.MCAP, 6074),
    ("rosbag2_cdr_test_mcap/cdr_test", Storage.MCAP, 7),
    ("rosbag2_cdr_test_sqlite3/cdr_test", Storage.SQLITE3, 7),
    ("rosbagjs_turtlesim/example.bag", Storage.ROS1, 8647),
    ("rosbagjs_turtlesim/example-lz4.bag", Storage.ROS1, 8647),
    ("rosbagjs_turtlesim/no-messages.bag", Storage.ROS1, 0),
    ("foxglove_chatter_db3/chatter.db3", Storage.SQLITE3, 7),
]


@pytest.mark.parametrize(
    ("relative", "storage", "count"),
    CATALOG,
    ids=[c[0].split("/")[0] + ":" + c[0].rsplit("/", 1)[-1] for c in CATALOG],
)
def test_real_bag_opens_and_streams_every_message(relative: str, storage: Storage, count: int) -> None:
    path = realbag(relative)
    with open_bag(str(path)) as reader:
        info = reader.info
        assert info.storage is storage
        assert info.message_count == count
        assert sum(t.count for t in info.topics) == count
        seen = 0
        last_ns = -1
        for message in reader.messages():
            assert message.log_time_ns >= last_ns
            last_ns = message.log_time_ns
            msg = message.msg()
            stamp = message.header_stamp_ns()
            header = getattr(msg, "header", None)
            if stamp is not None:
                assert header is not None
                assert stamp == header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
            seen += 1
        assert seen == count
        text = format_bag_info(info)
        assert f"Storage id:        {storage}" in text
        assert f"Messages:          {count}" in text


def test_topic_filter_and_ros2_type_names_for_ros1() -> None:
    path = realbag("rosbagjs_turtlesim/example.bag")
    with open_bag(str(path)) as reader:
        assert reader.info.topic("/turtle1/pose") is not None
        assert reader.info.topic("/turtle1/pose").msgtype == "turtlesim/msg/Pose"  # type: ignore[union-attr]
        poses = list(reader.messages(["/turtle1/pose"]))
        assert len(poses) == 1344
        assert {m.topic for m in poses} == {"/turtle1/pose"}
        assert poses[0].msg().x > 0


def test_custom_types_from_embedded_definitions() -> None:
    path = realbag("rosbag2_cdr_test_mcap/cdr_test")
    with open_bag(str(path)) as reader:
        msgs = [m.msg() for m in reader.messages(["/test_topic"])]
        assert type(msgs[0]).__name__.endswith("BasicTypes")


def test_remote_bag_through_fsspec(tmp_path: Path) -> None:
    source = realbag("rosbag2parquet/array_msgs")
    fs = fsspec.filesystem("memory")
    for item in source.iterdir():
        fs.pipe(f"/bags/array_msgs/{item.name}", item.read_bytes())
    with open_bag("memory://bags/array_msgs") as reader:
        assert reader.info.message_count == 2
        assert reader.info.uri == "memory://bags/array_msgs"
        assert len(list(reader.messages())) == 2


def test_corruption_ladder(tmp_path: Path) -> None:
    with pytest.raises(BagReadError, match=r"does not exist.*Fix: check the manifest uri"):
        open_bag(str(tmp_path / "missing.mcap"))
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    with pytest.raises(BagReadError, match="is an empty file, not a bag"):
        open_bag(str(empty))
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(b"definitely not a bag" * 10)
    with pytest.raises(BagReadError, match="is not a ROS bag"):
        open_bag(str(noise))
    compressed = (
        tmp_path / "episode_0.mcap.zstd"
    )  # rosbag2's compression_mode: file, given without its folder
    compressed.write_bytes(zstandard.ZstdCompressor().compress(b"\x89MCAP0\r\n" + b"\x00" * 64))
    with pytest.raises(BagReadError, match=r"is compressed whole with zstd .*Fix: give the bag's folder"):
        open_bag(str(compressed))
    folder = tmp_path / "folder"
    folder.mkdir()
    with pytest.raises(BagReadError, match=r"folder without metadata\.yaml"):
        open_bag(str(folder))
    mcap = realbag("rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap")
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(BagReadError, match=r"truncated\.mcap"), open_bag(str(truncated)) as reader:
        list(reader.messages())
    ros1 = realbag("rosbagjs_turtlesim/example.bag")
    truncated1 = tmp_path / "truncated.bag"
    truncated1.write_bytes(ros1.read_bytes()[:200_000])
    with pytest.raises(BagReadError, match=r"truncated\.bag"), open_bag(str(truncated1)) as reader:
        list(reader.messages())


def test_folder_named_like_a_ros1_bag_is_read_as_rosbag2(tmp_path: Path) -> None:
    copy = tmp_path / "images.bag"
    shutil.copytree(realbag("ros2bag_tools/images.bag"), copy)
    with open_bag(str(copy)) as reader:
        assert reader.info.storage is Storage.SQLITE3
        assert [m.msg().encoding for m in reader.messages()] == ["mono8"] * 3


@pytest.mark.parametrize(
    "relative",
    [
        "rosbagjs_turtlesim/example.bag",
        "foxglove_chatter_db3/chatter.db3",
        "rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap",
    ],
)
def test_files_are_read_by_content_whatever_their_name(tmp_path: Path, relative: str) -> None:
    source = realbag(relative)
    renamed = tmp_path / "recording.dat"
    shutil.copyfile(source, renamed)
    with open_bag(str(source)) as original, open_bag(str(renamed)) as copy:
        assert copy.info.storage is original.info.storage
        assert copy.info.message_count == original.info.message_count


def test_a_link_folder_is_made_only_for_a_file_that_needs_another_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A rosbag2 folder is read as it is: no scratch folder made and removed per bag (1-6 ms under load);
    an MCAP file without its suffix is read through a link in one, removed when the reader closes."""
    made: list[Path] = []

    def counted(kind: str) -> Path:
        made.append(scratch_dir(kind))
        return made[-1]

    monkeypatch.setattr("bagport.bags.reader.scratch_dir", counted)
    write_episode_bag(tmp_path / "folder", "mcap", EpisodeSpec(duration_s=0.2))
    with open_bag(str(tmp_path / "folder")) as bag:
        assert bag.info.message_count > 0
    assert made == []
    data = next((tmp_path / "folder").glob("*.mcap"))
    renamed = tmp_path / "recording.dat"
    renamed.write_bytes(data.read_bytes())
    with open_bag(str(renamed)) as bag:
        assert bag.info.message_count > 0
        assert len(made) == 1 and made[0].is_dir()
    assert not made[0].exists()
