"""Real-world bag layouts: split recordings, stale metadata.yaml, per-message compression, service
events and types that cannot be loaded, short reads, read-only SQLite, unindexed ROS 1 bags."""

from __future__ import annotations

import re
import shutil
import sqlite3
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags import open_bag
from bagport.bags.typeload import TolerantAnyReader
from bagport.errors import BagReadError
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import realbag

STORE = get_typestore(Stores.ROS2_HUMBLE)
STRING, BOOL = "std_msgs/msg/String", "std_msgs/msg/Bool"
STORE_ROS1 = get_typestore(Stores.ROS1_NOETIC)
STRING_ROS1, BOOL_ROS1 = "std_msgs/msg/String", "std_msgs/msg/Bool"
SPLIT = "rosbag2_split/wbag"
SPLIT_FILES = [f"wbag_{i}.mcap" for i in range(5)]


def _string(text: str) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[STRING](data=text), STRING))


def write_strings(
    path: Path,
    plugin: StoragePlugin = StoragePlugin.MCAP,
    compression: CompressionMode | None = None,
    count: int = 5,
) -> None:
    """A rosbag2 folder with ``count`` strings on /s and bools on /b."""
    writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    writer.open()
    text = writer.add_connection("/s", STRING, typestore=STORE)
    flag = writer.add_connection("/b", BOOL, typestore=STORE)
    for i in range(count):
        writer.write(text, 100 + i, _string(f"hello {i}"))
        writer.write(flag, 100 + i, bytes(STORE.serialize_cdr(STORE.types[BOOL](data=i % 2 == 0), BOOL)))
    writer.close()


def _edit_metadata(folder: Path, **changes: object) -> None:
    path = folder / "metadata.yaml"
    data = yaml.safe_load(path.read_text())
    data["rosbag2_bagfile_information"].update(changes)
    path.write_text(yaml.safe_dump(data))


def _copy_split(tmp_path: Path, name: str = "wbag") -> Path:
    copy = tmp_path / name
    shutil.copytree(realbag(SPLIT), copy)
    return copy


def _read_all(uri: Path) -> tuple[tuple[str, ...], list[tuple[str, int, str]]]:
    with open_bag(str(uri)) as reader:
        return reader.info.warnings, [(m.topic, m.log_time_ns, m.msg().data) for m in reader.messages()]


def test_split_recording_without_metadata_reads_as_one_bag_in_time_order(tmp_path: Path) -> None:
    with_metadata = _read_all(realbag(SPLIT))[1]
    folder = tmp_path / "no_metadata"
    folder.mkdir()
    for name in SPLIT_FILES:
        shutil.copyfile(realbag(SPLIT) / name, folder / name)
    warnings, messages = _read_all(folder)
    assert warnings == ()
    assert len(messages) == 6074
    assert [t for _, t, _ in messages] == sorted(t for _, t, _ in messages)
    assert sorted(messages) == sorted(with_metadata)
    with open_bag(str(folder)) as reader:
        assert reader.info.files == tuple(SPLIT_FILES)
        assert reader.info.message_count == 6074


def test_split_files_are_ordered_naturally_and_merged_by_log_time(tmp_path: Path) -> None:
    """rosbag2 numbers splits rec_0 ... rec_10: the names sort badly, the messages must not."""
    for part, first in ((9, 0), (10, 5)):
        out = tmp_path / f"part{part}"
        writer = Ros2Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        conn = writer.add_connection("/s", STRING, typestore=STORE)
        for i in range(first, first + 5):
            writer.write(conn, 1_000 + i, _string(f"m{i}"))
        writer.close()
    folder = tmp_path / "rec"
    folder.mkdir()
    shutil.move(tmp_path / "part9" / "part9.mcap", folder / "rec_9.mcap")
    shutil.move(tmp_path / "part10" / "part10.mcap", folder / "rec_10.mcap")
    with open_bag(str(folder)) as reader:
        assert reader.info.files == ("rec_10.mcap", "rec_9.mcap")
        assert [m.msg().data for m in reader.messages()] == [f"m{i}" for i in range(10)]


def test_metadata_with_empty_storage_id_reads_the_files_present_and_warns(tmp_path: Path) -> None:
    folder = _copy_split(tmp_path)
    _edit_metadata(folder, storage_identifier="")
    warnings, messages = _read_all(folder)
    assert len(messages) == 6074
    assert len(warnings) == 1
    assert re.search(r"storage id ''; reading the 5 mcap file\(s\) present instead", warnings[0])


def test_metadata_listing_a_missing_file_is_an_incomplete_recording(tmp_path: Path) -> None:
    """A split file lost (or not copied yet) is refused, not read as a shorter episode that looks whole."""
    folder = _copy_split(tmp_path)
    _edit_metadata(folder, relative_file_paths=SPLIT_FILES)
    (folder / "wbag_4.mcap").unlink()
    with pytest.raises(BagReadError) as caught:
        open_bag(str(folder)).close()
    message = str(caught.value)
    assert "lists 5 data file(s) but the folder holds 4: ['wbag_4.mcap'] missing" in message
    assert "remove metadata.yaml" in message
    (folder / "metadata.yaml").unlink()  # the documented way to convert what is there
    warnings, messages = _read_all(folder)
    with open_bag(str(realbag(SPLIT) / "wbag_4.mcap")) as last:
        assert len(messages) == 6074 - last.info.message_count
    assert warnings == ()


def test_metadata_naming_renamed_files_reads_them_and_warns(tmp_path: Path) -> None:
    folder = _copy_split(tmp_path)
    _edit_metadata(folder, relative_file_paths=[f"old_{i}.mcap" for i in range(5)])
    warnings, messages = _read_all(folder)
    assert len(messages) == 6074
    assert "reading the 5 mcap file(s) present" in warnings[0]


def test_metadata_missing_a_file_of_the_folder_reads_every_file_and_warns(tmp_path: Path) -> None:
    folder = _copy_split(tmp_path)
    _edit_metadata(folder, relative_file_paths=SPLIT_FILES[:3])
    warnings, messages = _read_all(folder)
    assert len(messages) == 6074
    assert "reading the 5 mcap file(s) present" in warnings[0]


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3], ids=["mcap", "sqlite3"])
@pytest.mark.parametrize("mode", [CompressionMode.MESSAGE, CompressionMode.FILE], ids=["message", "file"])
def test_zstd_compressed_bags(tmp_path: Path, plugin: StoragePlugin, mode: CompressionMode) -> None:
    folder = tmp_path / "compressed"
    write_strings(folder, plugin, mode)
    with open_bag(str(folder)) as reader:
        assert [m.msg().data for m in reader.messages(["/s"])] == [f"hello {i}" for i in range(5)]


def test_message_compression_survives_a_stale_metadata(tmp_path: Path) -> None:
    folder = tmp_path / "compressed"
    write_strings(folder, StoragePlugin.MCAP, CompressionMode.MESSAGE)
    _edit_metadata(folder, storage_identifier="")
    warnings, messages = _read_all(folder)
    assert warnings
    assert [text for topic, _, text in messages if topic == "/s"] == [f"hello {i}" for i in range(5)]


def test_file_compression_with_a_stale_metadata_is_a_clear_error(tmp_path: Path) -> None:
    folder = tmp_path / "compressed"
    write_strings(folder, StoragePlugin.MCAP, CompressionMode.FILE)
    _edit_metadata(folder, relative_file_paths=["other.mcap.zstd"])
    with pytest.raises(BagReadError, match=r"compressed whole.*Fix: fix relative_file_paths"):
        open_bag(str(folder))


_ADD_TWO_INTS_EVENT = """service_msgs/ServiceEventInfo info
AddTwoInts_Request[<=1] request
AddTwoInts_Response[<=1] response
================================================================================
MSG: service_msgs/ServiceEventInfo
builtin_interfaces/Time stamp
int64 sequence_number
================================================================================
MSG: example_interfaces/AddTwoInts_Request
int64 a
================================================================================
MSG: example_interfaces/AddTwoInts_Response
int64 sum
"""


def test_service_event_topics_are_listed_but_not_read(tmp_path: Path) -> None:
    path = tmp_path / "services.mcap"
    with path.open("wb") as handle:
        writer = McapWriter(handle)
        writer.start(profile="ros2")
        text = STORE.generate_msgdef(STRING, ros_version=2)[0]
        chatter = writer.register_channel(
            "/chatter", "cdr", writer.register_schema(STRING, "ros2msg", text.encode())
        )
        event_t = "example_interfaces/srv/AddTwoInts_Event"
        event_schema = writer.register_schema(event_t, "ros2msg", _ADD_TWO_INTS_EVENT.encode())
        event = writer.register_channel("/add/_service_event", "cdr", event_schema)
        for i in range(3):
            writer.add_message(chatter, log_time=10 + i, data=_string(f"hi {i}"), publish_time=10 + i)
            writer.add_message(
                event, log_time=10 + i, data=b"\x00\x01\x00\x00" + bytes(40), publish_time=10 + i
            )
        writer.finish()  # type: ignore[no-untyped-call]
    with open_bag(str(path)) as reader:
        assert [t.name for t in reader.info.topics] == ["/add/_service_event", "/chatter"]
        assert [m.topic for m in reader.messages()] == ["/chatter"] * 3


def test_a_type_that_cannot_be_loaded_fails_only_the_topics_that_use_it(tmp_path: Path) -> None:
    folder = tmp_path / "hash"
    write_strings(folder)
    metadata = (folder / "metadata.yaml").read_text()
    stale = re.sub(r"(type_description_hash: RIHS01_)([0-9a-f]+)", r"\g<1>" + "0" * 64, metadata, count=1)
    assert stale != metadata
    (folder / "metadata.yaml").write_text(stale)
    with open_bag(str(folder)) as reader:
        assert reader.info.warnings == (
            f"type {STRING} cannot be loaded: its definition hashes to "
            f"{STORE.hash_rihs01(STRING)}, the bag records RIHS01_{'0' * 64}",
        )
        assert [m.msg().data for m in reader.messages(["/b"])] == [True, False, True, False, True]
        assert {m.topic for m in reader.messages()} == {"/b"}
        with pytest.raises(
            BagReadError,
            match=r"topic /s has type std_msgs/msg/String, which cannot be loaded: its definition hashes to RIHS01_\w+, the bag records RIHS01_0+",
        ):
            list(reader.messages(["/s"]))


def _write_strings_promising_seven(folder: Path) -> None:
    """The strings bag (5 messages per topic) whose metadata.yaml promises 7 on /s."""
    write_strings(folder)
    data = yaml.safe_load((folder / "metadata.yaml").read_text())
    for entry in data["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if entry["topic_metadata"]["name"] == "/s":
            entry["message_count"] = 7
    (folder / "metadata.yaml").write_text(yaml.safe_dump(data))


def test_fewer_messages_than_the_index_promises_is_an_error_naming_topic_and_counts(tmp_path: Path) -> None:
    folder = tmp_path / "short"
    _write_strings_promising_seven(folder)
    with open_bag(str(folder)) as reader:
        assert len(list(reader.messages(["/b"]))) == 5
        with pytest.raises(BagReadError, match=r"yielded 5 messages on /s, its index promises 7.*reindex"):
            list(reader.messages(["/s"]))


def _write_strings_any(path: Path, storage: str) -> Path:
    """``write_strings`` in MCAP, SQLite or ROS 1 (``path.bag``); returns what to open."""
    if storage != "ros1":
        write_strings(path, StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)
        return path
    bag = path.with_suffix(".bag")
    with Ros1Writer(bag) as writer:
        text = writer.add_connection("/s", STRING_ROS1, typestore=STORE_ROS1)
        flag = writer.add_connection("/b", BOOL_ROS1, typestore=STORE_ROS1)
        for i in range(5):
            writer.write(
                text,
                100 + i,
                STORE_ROS1.serialize_ros1(STORE_ROS1.types[STRING_ROS1](data=f"hi {i}"), STRING_ROS1),
            )
            writer.write(
                flag, 100 + i, STORE_ROS1.serialize_ros1(STORE_ROS1.types[BOOL_ROS1](data=True), BOOL_ROS1)
            )
    return bag


def _drop_first_message_on(topic: str) -> Callable[..., Iterator[tuple[Any, int, bytes]]]:
    """``TolerantAnyReader.messages`` that loses the first message on ``topic``: a short reader."""
    original = TolerantAnyReader.messages

    def messages(self: TolerantAnyReader, *args: Any, **kwargs: Any) -> Iterator[tuple[Any, int, bytes]]:
        dropped = False
        for conn, log_ns, raw in original(self, *args, **kwargs):
            if conn.topic == topic and not dropped:
                dropped = True
                continue
            yield conn, log_ns, raw

    return messages


FORMATS = ["mcap", "sqlite3", "ros1"]


@pytest.mark.parametrize("storage", FORMATS)
def test_windowed_read_yielding_fewer_messages_than_the_index_promises_is_an_error(
    tmp_path: Path, storage: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = _write_strings_any(tmp_path / "short", storage)
    monkeypatch.setattr(TolerantAnyReader, "messages", _drop_first_message_on("/s"))
    with open_bag(str(bag)) as reader:
        assert len(list(reader.messages(["/b"], start_ns=101, stop_ns=104))) == 3
        with pytest.raises(
            BagReadError,
            match=r"short.*yielded 2 messages on /s in \[101, 104\) ns, its index promises 3.*reindex",
        ):
            list(reader.messages(["/s", "/b"], start_ns=101, stop_ns=104))


@pytest.mark.parametrize("storage", FORMATS)
@pytest.mark.parametrize(
    ("start_ns", "stop_ns", "expected"),
    [(101, 104, 3), (104, 105, 1), (0, 102, 2), (103, None, 2), (200, 300, 0), (None, None, 5)],
    ids=["straddles", "last", "head", "tail", "after", "whole"],
)
def test_windowed_read_of_a_healthy_bag_passes_the_check(
    tmp_path: Path, storage: str, start_ns: int | None, stop_ns: int | None, expected: int
) -> None:
    bag = _write_strings_any(tmp_path / "healthy", storage)
    with open_bag(str(bag)) as reader:
        topics = [m.topic for m in reader.messages(start_ns=start_ns, stop_ns=stop_ns)]
    assert sorted(topics) == ["/b"] * expected + ["/s"] * expected


def test_window_holding_the_whole_bag_is_checked_against_metadata(tmp_path: Path) -> None:
    folder = tmp_path / "stale"
    _write_strings_promising_seven(folder)
    with open_bag(str(folder)) as reader:
        assert len(list(reader.messages(["/s"], start_ns=101, stop_ns=103))) == 2  # the index agrees
        with pytest.raises(
            BagReadError, match=r"yielded 5 messages on /s in \[0, 1000\) ns, its index promises 7"
        ):
            list(reader.messages(["/s"], start_ns=0, stop_ns=1000))


def test_sqlite_bags_are_read_without_writing_beside_them(tmp_path: Path) -> None:
    folder = tmp_path / "ro"
    write_strings(folder, StoragePlugin.SQLITE3)
    db = folder / "ro.db3"
    with sqlite3.connect(db) as conn:  # WAL mode: a normal reader would create -wal and -shm files
        conn.execute("PRAGMA journal_mode=WAL")
    assert not (folder / "ro.db3-wal").exists()
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    db.chmod(stat.S_IRUSR)
    try:
        with open_bag(str(folder)) as reader:
            assert len(list(reader.messages())) == 10
        with open_bag(str(db)) as reader:
            assert len(list(reader.messages())) == 10
    finally:
        folder.chmod(stat.S_IRWXU)
        db.chmod(stat.S_IRUSR | stat.S_IWUSR)
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == before


def test_unindexed_ros1_bag_says_to_reindex(tmp_path: Path) -> None:
    path = tmp_path / "unindexed.bag"
    write_episode_bag(path, "ros1", EpisodeSpec(duration_s=0.3, seed=4))
    raw = bytearray(path.read_bytes())
    at = raw.index(b"index_pos=") + len(b"index_pos=")
    raw[at : at + 8] = bytes(8)  # as a recorder killed before closing leaves it
    path.write_bytes(bytes(raw))
    with pytest.raises(
        BagReadError, match=r"unindexed\.bag.*not indexed.*Fix: reindex the bag \(`rosbag reindex`"
    ):
        open_bag(str(path))


def test_truncated_ros1_bag_says_to_reindex(tmp_path: Path) -> None:
    source = realbag("rosbagjs_turtlesim/example.bag")
    path = tmp_path / "cut.bag"
    path.write_bytes(source.read_bytes()[: source.stat().st_size * 2 // 3])
    with pytest.raises(BagReadError, match=r"cut\.bag.*`rosbag reindex`"), open_bag(str(path)) as reader:
        list(reader.messages())
    assert [p.name for p in tmp_path.iterdir()] == ["cut.bag"]


def test_a_data_file_named_for_another_storage_is_read_by_its_content(tmp_path: Path) -> None:
    folder = _copy_split(tmp_path)
    (folder / "wbag_2.mcap").rename(folder / "wbag_2.db3")
    warnings, messages = _read_all(folder)
    assert len(messages) == 6074
    assert "wbag_2.db3 read as .mcap by their content" in warnings[0]
    (folder / "metadata.yaml").unlink()  # without metadata.yaml too
    warnings, messages = _read_all(folder)
    assert len(messages) == 6074
    assert warnings == ("data file(s) named for another storage (wbag_2.db3 read as .mcap by their content)",)


def test_a_folder_of_ros1_bags_says_so_and_how_to_convert_them(tmp_path: Path) -> None:
    folder = tmp_path / "ros1s"
    folder.mkdir()
    for name in ("a.bag", "b.bag"):
        shutil.copyfile(realbag("rosbagjs_turtlesim/example.bag"), folder / name)
    with pytest.raises(BagReadError) as caught:
        open_bag(str(folder)).close()
    message = str(caught.value)
    assert "is a folder of 2 ROS 1 bag(s) (a.bag, b.bag), not one recording" in message
    assert "--glob 'FOLDER/*.bag'" in message


def _mcap_and_sqlite(tmp_path: Path, metadata_of: StoragePlugin | None) -> Path:
    """A folder holding a 10-message MCAP recording (m.mcap) and a 6-message SQLite one (s.db3), with the
    metadata.yaml of the one ``metadata_of`` names (none: no metadata.yaml)."""
    write_strings(tmp_path / "m", StoragePlugin.MCAP, count=5)
    write_strings(tmp_path / "s", StoragePlugin.SQLITE3, count=3)
    folder = tmp_path / "both"
    folder.mkdir()
    shutil.copyfile(tmp_path / "m/m.mcap", folder / "m.mcap")
    shutil.copyfile(tmp_path / "s/s.db3", folder / "s.db3")
    if metadata_of is not None:
        source = "m" if metadata_of == StoragePlugin.MCAP else "s"
        shutil.copyfile(tmp_path / source / "metadata.yaml", folder / "metadata.yaml")
    return folder


@pytest.mark.parametrize(
    ("plugin", "count", "ignored"),
    [(StoragePlugin.MCAP, 10, "s.db3"), (StoragePlugin.SQLITE3, 6, "m.mcap")],
    ids=["metadata-mcap", "metadata-sqlite3"],
)
def test_mcap_and_sqlite_in_one_folder_read_the_storage_metadata_names_and_warn(
    tmp_path: Path, plugin: StoragePlugin, count: int, ignored: str
) -> None:
    """As rosbag2 does, metadata.yaml says which files are the recording (the MCAP used to win whatever it
    said); the other file is ignored, with a warning naming it."""
    folder = _mcap_and_sqlite(tmp_path, plugin)
    warnings, messages = _read_all(folder)
    assert len(messages) == count
    assert warnings == (
        f"{ignored} ignored: not part of the {plugin.name.lower()} recording metadata.yaml describes (Fix: move "
        "it out of the bag folder)",
    )
    with open_bag(str(folder)) as reader:
        assert ignored not in reader.info.files


@pytest.mark.parametrize("storage_id", [None, ""], ids=["no-metadata", "metadata-without-storage"])
def test_mcap_and_sqlite_in_one_folder_without_metadata_naming_one_is_refused(
    tmp_path: Path, storage_id: str | None
) -> None:
    """Which of the two is the recording is unknown: the MCAP used to be read without a word."""
    folder = _mcap_and_sqlite(tmp_path, None if storage_id is None else StoragePlugin.MCAP)
    if storage_id is not None:
        _edit_metadata(folder, storage_identifier=storage_id)
    with pytest.raises(BagReadError) as caught:
        open_bag(str(folder)).close()
    assert caught.value.uri == str(folder)
    said = "no metadata.yaml says which" if storage_id is None else "its metadata.yaml names neither"
    assert f"holds both MCAP (m.mcap) and SQLite (s.db3) data files, and {said}" in str(caught.value)
    assert "Fix: move the files that are not part of this recording out of the folder, or write its " in str(
        caught.value
    )


def test_a_file_compressed_mcap_gives_its_publish_times(tmp_path: Path) -> None:
    """``ros2 bag record -s mcap --compression-mode file`` writes ``.mcap.zstd`` files: their publish times are
    read through the decompression (they were refused as 'invalid magic'), the same as the plain file's; and a
    contract that asks for none (header or receive stamps) opens no file for them."""
    plain, packed = tmp_path / "plain", tmp_path / "packed"
    write_strings(plain, StoragePlugin.MCAP)
    write_strings(packed, StoragePlugin.MCAP, CompressionMode.FILE)
    assert [p.name for p in packed.iterdir() if p.suffix == ".zstd"] == ["packed.mcap.zstd"]
    with open_bag(str(plain)) as reader:
        expected = reader.publish_times_ns(["/s", "/b"])
    with open_bag(str(packed)) as reader:
        found = reader.publish_times_ns(["/s", "/b"])
        assert reader.publish_times_ns([]) == {}
        checksums = reader.info.checksums
    # the MCAP inside is read through its decompression: said as such, not as a summary that cannot be read
    assert checksums is not None and not checksums.checked
    assert (
        checksums.detail
        == "MCAP compressed as a whole file (packed.mcap.zstd): its chunks' CRCs are not checked"
    )
    assert "instead of `--compression-mode file`" in checksums.fix
    assert sorted(found) == sorted(expected) == ["/b", "/s"]
    for topic, (log_ns, publish_ns) in expected.items():
        assert found[topic][0].tolist() == log_ns.tolist() == [100, 101, 102, 103, 104]
        assert found[topic][1].tolist() == publish_ns.tolist()
