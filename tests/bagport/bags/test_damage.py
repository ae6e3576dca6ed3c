"""Damage is refused with one paragraph naming the file, the byte offset (or the record), the topic and the
fix, per format: chunked MCAP with CRCs, SQLite, ROS 1 (compressed chunks and record layout); and a
metadata.yaml that contradicts the files is named, not the intact data file."""

from __future__ import annotations

import re
import shutil
import sqlite3
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags import format_bag_info, open_bag
from bagport.bags.publish import mcap_publish_times_ns
from bagport.errors import BagportError, BagReadError, DecodeError
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import realbag

SPEC = EpisodeSpec(duration_s=3.0, cameras=(), mcap_crcs=True)
STORE_ROS1 = get_typestore(Stores.ROS1_NOETIC)


def _flip(path: Path, offset: int, mask: int = 0x10) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= mask
    path.write_bytes(bytes(data))


def _read_all(bag: Path) -> int:
    with open_bag(str(bag)) as reader:
        return sum(1 for message in reader.messages() if message.msg() is not None)


def _one_paragraph(err: BagportError) -> str:
    text = str(err)
    assert "\n" not in text and "Fix: " in text, text
    return text


def _chunk_offsets(mcap: Path) -> list[int]:
    with mcap.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    return sorted(c.chunk_start_offset for c in summary.chunk_indexes)


def test_mcap_chunk_crc_mismatch_names_the_chunk_offset_and_its_topics(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", SPEC)
    mcap = bag / "ep.mcap"
    chunks = _chunk_offsets(mcap)
    assert len(chunks) >= 2  # 64 KiB chunks
    _flip(mcap, chunks[1] + 200)  # inside the second chunk's records
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert f"reading failed: ep.mcap at byte offset {chunks[1]}: chunk fails its CRC-32 check" in text
    assert "Chunk checksum mismatch" not in text  # located: the reader's words add nothing
    assert re.search(r"it holds messages of [^)]*/joint_states", text)
    assert "Fix: copy the file again from the robot or a backup" in text and "reindex`" not in text


def test_sqlite_page_damage_names_the_page_offset(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    db3 = bag / "ep.db3"
    with sqlite3.connect(db3) as db:
        payload = db.execute("SELECT data FROM messages WHERE id = 50").fetchone()[0]
    data = db3.read_bytes()
    page_size = int.from_bytes(data[16:18], "big")
    page_start = data.index(payload) // page_size * page_size
    assert page_start > 0 and data[page_start] == 0x0D  # a leaf page of the messages table
    _flip(db3, page_start, 0xFF)  # its b-tree page type
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert "database disk image is malformed" not in text  # located: the reader's words add nothing
    page = page_start // page_size + 1
    assert f"ep.db3 at byte offset {page_start}: page {page} of messages has a damaged b-tree header" in text
    assert "Fix: copy the bag again" in text and ".dump" in text


def test_sqlite_row_holding_a_number_where_the_message_belongs_names_topic_and_time(tmp_path: Path) -> None:
    """The issue's case: a damaged row made conversion fail with "TypeError: object of type 'int' has no
    len()" while ``inspect`` opened the bag fine."""
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    with sqlite3.connect(bag / "ep.db3") as db:
        db.execute("UPDATE messages SET data = 12345 WHERE id = 7")
        (log_ns,) = db.execute("SELECT timestamp FROM messages WHERE id = 6").fetchone()
        (topic,) = db.execute(
            "SELECT topics.name FROM messages JOIN topics ON topics.id = topic_id WHERE messages.id = 7"
        ).fetchone()
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert (
        f"the message record on {topic} after log time {log_ns} ns is damaged: its payload is a int" in text
    )
    assert f"[topic={topic}]" in text and "TypeError" not in text


def test_sqlite_bit_flip_in_a_record_header_names_the_record(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    db3 = bag / "ep.db3"
    with sqlite3.connect(db3) as db:
        payload = db.execute("SELECT data FROM messages WHERE id = 5").fetchone()[0]
    data = db3.read_bytes()
    at = (
        data.index(payload) - 12
    )  # record header: ..., 0x06 (int64 timestamp), blob size, topic id, timestamp
    assert data[at] == 0x06
    _flip(db3, at)  # the timestamp column now reads as a 5-byte blob
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert re.search(r"ep\.db3.*; the last intact message read was on /\S+ at log time \d+ ns", text)


def _ros1_strings(path: Path, count: int = 200) -> None:
    writer = Ros1Writer(path)
    writer.set_compression(Ros1Writer.CompressionFormat.BZ2)
    writer.open()
    conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=STORE_ROS1)
    msg = STORE_ROS1.types["std_msgs/msg/String"]
    for i in range(count):
        writer.write(
            conn, 1_000 + i, STORE_ROS1.serialize_ros1(msg(data=f"hello {i}" * 20), "std_msgs/msg/String")
        )
    writer.close()


def _ros1_chunk_offset(path: Path) -> int:
    data = path.read_bytes()
    op = data.index(b"op=\x05")
    return data.rindex(b"\x00\x00", 13, op) - 2  # the record starts with its 4-byte header length


def test_sqlite_schema_holding_bytes_that_are_not_text_is_named(tmp_path: Path) -> None:
    """A byte of the schema's SQL changed to one no UTF-8 text holds: SQLite's own error quotes it, and
    Python's sqlite3 failed decoding that message (a UnicodeDecodeError escaped the damage report)."""
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    db3 = next(bag.glob("*.db3"))
    data = bytearray(db3.read_bytes())
    data[data.index(b"ros_distro TEXT NOT NULL") + 20] = 0xB1  # NOT NULL -> NOT \xb1ULL: bad schema SQL
    db3.write_bytes(bytes(data))
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert (
        "cannot be opened: ep.db3: SQLite cannot read its schema (it holds bytes that are not text)" in text
    )


def test_an_mcap_summary_missing_a_channel_is_damage_also_for_publish_times(tmp_path: Path) -> None:
    """The mcap library (publish times, ``stamp: publish``) raised a bare KeyError for a chunk index naming a
    channel the summary does not define."""
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", SPEC)
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    position = int.from_bytes(data[-28:-20], "little")  # the footer's summary start
    while data[position] != 0x04:  # the summary's first channel record
        position += 9 + int.from_bytes(data[position + 1 : position + 9], "little")
    data[position] = 0x80  # now a private record a reader skips: the channel is gone from the summary
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagReadError) as caught:
        mcap_publish_times_ns([mcap], ["/joint_states", "/cmd"], str(bag))
    text = _one_paragraph(caught.value)
    assert text.startswith(f"{bag}: its publish times cannot be read: ep.mcap at byte offset ")
    assert "KeyError" not in text


def test_ros1_chunk_that_does_not_decompress_names_its_offset(tmp_path: Path) -> None:
    bag = tmp_path / "chat.bag"
    _ros1_strings(bag)
    data = bag.read_bytes()
    chunk = data.index(b"BZh")  # the bz2 stream of the first chunk
    _flip(bag, chunk + 100)
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert re.search(r"chat\.bag at byte offset \d+: record damaged: chunk does not decompress \(bz2: ", text)
    offset = int(re.search(r"at byte offset (\d+)", text).group(1))  # type: ignore[union-attr]
    assert offset < chunk < offset + 200  # the chunk record holding the stream
    assert "Fix: copy the bag again from the robot or a backup" in text


def test_ros1_record_layout_damage_names_the_record_offset(tmp_path: Path) -> None:
    bag = tmp_path / "ep.bag"
    write_episode_bag(bag, "ros1", SPEC)
    data = bag.read_bytes()
    field = data.index(b"\x00op=\x02") - 3  # the length of a message record's op field, inside a chunk
    _flip(bag, field + 2, 0x40)
    with pytest.raises(BagportError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    found = re.search(
        r"ep\.bag at byte offset (\d+): record damaged: record at byte (\d+) of the chunk is damaged", text
    )
    assert found is not None, text
    chunk_at, inside = int(found.group(1)), int(found.group(2))
    assert chunk_at < field and 0 < inside < field - chunk_at  # the chunk's offset, then the record's in it


def test_ros1_damaged_message_payload_is_a_decode_error_with_topic_and_time(tmp_path: Path) -> None:
    bag = tmp_path / "ep.bag"
    write_episode_bag(bag, "ros1", SPEC)
    data = bag.read_bytes()
    names = data.index(b"\x02\x00\x00\x00j1")  # the first JointState's name list: length of "j1"
    _flip(bag, names + 3, 0x40)  # "j1" now claims 64 MiB more bytes than the message holds
    with pytest.raises(DecodeError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    assert re.search(
        r"ep\.bag: a message of type sensor_msgs/msg/JointState does not match the definition embedded in the "
        r"bag \(the bytes do not fit: .*\).*Fix: the message's bytes are damaged",
        text,
    )
    assert re.search(r"\[topic=/(cmd|joint_states), t_ns=\d+\]", text)


def test_wrong_storage_identifier_names_metadata_yaml_and_reads_by_content(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    expected = _read_all(bag)
    metadata = bag / "metadata.yaml"
    info = yaml.safe_load(metadata.read_text())
    info["rosbag2_bagfile_information"]["storage_identifier"] = "mcap"
    metadata.write_text(yaml.safe_dump(info))
    assert _read_all(bag) == expected  # the intact data file is read, not blamed
    with open_bag(str(bag)) as reader:
        (warning,) = reader.info.warnings
        text = format_bag_info(reader.info)
    assert "metadata.yaml says storage_identifier: mcap, but ep.db3 is sqlite3 by its content" in warning
    assert "Fix: set storage_identifier: sqlite3 in metadata.yaml" in warning
    assert "file is not a database" not in text


def test_damaged_signature_with_metadata_names_the_data_file(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", SPEC)
    _flip(bag / "ep.db3", 3)
    with pytest.raises(BagReadError, match=r"ep\.db3 has no ROS 1, MCAP or SQLite signature at its start"):
        open_bag(str(bag))


@pytest.mark.parametrize(
    ("storage", "crcs", "line"),
    [
        ("mcap", True, "Checksums:         verified on every read: MCAP chunk CRC-32s"),
        ("mcap", False, "Warning:           MCAP without chunk CRCs (ep.mcap was written with CRCs off)"),
        ("sqlite3", False, "Warning:           rosbag2 SQLite (.db3) bags carry no checksums"),
        ("ros1", False, "Warning:           ROS 1 bags carry no checksums"),
    ],
    ids=["mcap-crcs", "mcap-no-crcs", "sqlite3", "ros1"],
)
def test_inspect_says_whether_the_bag_carries_checksums(
    tmp_path: Path, storage: str, crcs: bool, line: str
) -> None:
    bag = tmp_path / ("ep.bag" if storage == "ros1" else "ep")
    write_episode_bag(bag, storage, EpisodeSpec(duration_s=0.3, cameras=(), mcap_crcs=crcs))  # type: ignore[arg-type]
    with open_bag(str(bag)) as reader:
        text = format_bag_info(reader.info)
        assert reader.info.checksums is not None and reader.info.checksums.checked == crcs
    assert line in text
    assert ("Fix: " in text) != crcs


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_no_bit_flip_escapes_as_a_raw_exception(tmp_path: Path, storage: str) -> None:
    """A sweep of flips over a small bag of each format (MCAP without CRCs: nothing refuses a changed
    byte early): every read either succeeds or fails with one bagport paragraph, never a library error."""
    clean = tmp_path / ("clean.bag" if storage == "ros1" else "clean")
    write_episode_bag(clean, storage, EpisodeSpec(duration_s=0.3, cameras=()))  # type: ignore[arg-type]
    source = clean if storage == "ros1" else next(p for p in clean.iterdir() if p.suffix in (".mcap", ".db3"))
    data = source.read_bytes()
    refused = 0
    for offset in range(5, len(data), len(data) // 60):
        bag = tmp_path / f"flip{offset}"
        if storage == "ros1":
            bag.write_bytes(data)
            target = bag
        else:
            shutil.copytree(clean, bag)
            target = bag / source.name
        _flip(target, offset)
        try:
            _read_all(bag)
        except BagportError as err:
            _one_paragraph(err)
            refused += 1
    assert refused > 0


def test_a_real_compressed_mcap_with_chunk_crcs_refuses_a_changed_byte(tmp_path: Path) -> None:
    bag = tmp_path / "wbag"
    shutil.copytree(realbag("rosbag2_split/wbag"), bag)
    chunk = _chunk_offsets(bag / "wbag_2.mcap")[0]
    _flip(bag / "wbag_2.mcap", chunk + 100)
    with pytest.raises(BagReadError) as caught:
        _read_all(bag)
    text = _one_paragraph(caught.value)
    # its chunks are zstd-compressed: the flip breaks the stream before the CRC is reached
    assert re.search(
        rf"wbag_2\.mcap at byte offset {chunk}: chunk (fails its CRC-32|does not decompress)", text
    )
