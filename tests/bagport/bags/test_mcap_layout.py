"""Damage to an MCAP file's framing (record lengths, the summary's records and CRC, the footer) is named by
file and byte offset with the fix for changed bytes: never the reader's ``OverflowError`` or a
``__schemaless__`` type, never a reindex. A zeroed CRC field among chunks with CRCs is damage, not a bag
written without CRCs."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest

from bagport.bags import format_bag_info, open_bag
from bagport.bags.damage import damaged_bag
from bagport.bags.mcap_layout import FIX as MCAP_FIX
from bagport.bags.mcap_layout import header_profile
from bagport.bags.records import Storage
from bagport.errors import BagReadError
from bagport.synth import EpisodeSpec, write_episode_bag

CRCS = EpisodeSpec(duration_s=3.0, cameras=(), mcap_crcs=True)
"""Written by the mcap library: 64 KiB chunks, chunk and summary CRCs."""
NO_CRCS = EpisodeSpec(duration_s=0.3, cameras=())
"""Written by rosbags: no summary CRC."""
COPY_AGAIN = "Fix: copy the file again from the robot or a backup"


def _bag(tmp_path: Path, spec: EpisodeSpec) -> tuple[Path, Path]:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", spec)
    return bag, bag / "ep.mcap"


def _records(data: bytes, start: int) -> list[tuple[int, int]]:
    """(offset, opcode) of the records from ``start`` to the footer, independently of the code tested."""
    pos, out = start, []
    while data[pos] != 0x02:
        out.append((pos, data[pos]))
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    return out


def _summary(data: bytes) -> list[tuple[int, int]]:
    return _records(data, struct.unpack_from("<Q", data, len(data) - 8 - 20)[0])


def _refusal(bag: Path) -> str:
    with pytest.raises(BagReadError) as caught, open_bag(str(bag)) as reader:
        for message in reader.messages():
            message.msg()
    text = str(caught.value)
    assert "\n" not in text and caught.value.uri == str(bag), text
    assert not re.search(r"reindex`|__schemaless__|--msg-path|Error\b", text), text
    return text


def test_a_record_length_past_the_file_names_the_record_not_an_overflow(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    data[8 + 8] ^= 0x80  # the header record's length: 2**63 and more
    mcap.write_bytes(bytes(data))
    text = _refusal(bag)
    assert re.search(
        rf"cannot be opened: ep\.mcap at byte offset 8: the header \(opcode 0x01\) is damaged: its length \d+ "
        rf"runs past .* \(the file has {len(data)} bytes\)",
        text,
    )
    assert COPY_AGAIN in text


def test_a_flipped_chunk_index_names_its_offset(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    index_at = next(pos for pos, opcode in _summary(bytes(data)) if opcode == 0x08)
    data[index_at + 9 + 16 + 5] ^= 0x02  # its chunk_start_offset, far past the data section
    mcap.write_bytes(bytes(data))
    text = _refusal(bag)
    assert f"ep.mcap at byte offset {index_at}: the summary's chunk index (opcode 0x08) is damaged: " in text
    assert "outside the data section" in text and COPY_AGAIN in text


def test_a_schema_lost_from_the_summary_is_damage_not_a_schemaless_type(tmp_path: Path) -> None:
    """rosbags reads a channel whose schema record is gone as type ``__schemaless__``, which bagport then
    asked for with --msg-path."""
    bag, mcap = _bag(tmp_path, NO_CRCS)
    data = bytearray(mcap.read_bytes())
    schema_at = next(pos for pos, opcode in _summary(bytes(data)) if opcode == 0x03)
    data[schema_at] = 0x80  # a private record, which readers skip: the schema is gone
    mcap.write_bytes(bytes(data))
    text = _refusal(bag)
    found = re.search(
        r"cannot be opened: ep\.mcap at byte offset (\d+): the summary's channel \d+ \(/\S+\) names schema \d+, "
        r"which the summary lacks",
        text,
    )
    assert found is not None, text
    assert (int(found[1]), 0x04) in _summary(bytes(data)) and COPY_AGAIN in text


def test_a_summary_failing_its_crc_is_refused_though_it_parses(tmp_path: Path) -> None:
    """A changed letter of a message definition: rosbags would read on with a different type."""
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    summary_at = _summary(bytes(data))[0][0]
    data[data.index(b"float64[] position", summary_at) + 2] ^= 0x01  # 'float64' -> 'flnat64'
    mcap.write_bytes(bytes(data))
    text = _refusal(bag)
    assert re.search(
        rf"cannot be opened: ep\.mcap at byte offset {summary_at}: the summary section \(bytes {summary_at} to "
        rf"{len(data) - 8}\) fails its CRC-32 check",
        text,
    )
    assert COPY_AGAIN in text


def test_a_zeroed_profile_in_a_rosbag2_bag_is_damage_at_the_header(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    data[17:21] = bytes(4)  # the header's profile: "" (no framing damage: its length still fits)
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagReadError) as caught:
        open_bag(str(bag))
    assert str(caught.value) == (
        f"{bag}: cannot be opened: ep.mcap at byte offset 8: its header record names profile '' where rosbag2, "
        "which recorded this bag (its metadata.yaml), writes 'ros2': its bytes changed after recording Fix: "
        f"{MCAP_FIX}"
    )


def test_damage_bagport_cannot_locate_quotes_the_reader(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    error = damaged_bag(
        ValueError("a reason of the reader's own"),
        uri=str(bag), storage=Storage.MCAP, files=[mcap], action="cannot be opened", metadata_yaml=True,
    )  # fmt: skip
    assert "cannot be opened; the reader said: ValueError: a reason of the reader's own" in str(error)


def test_a_zeroed_first_chunk_crc_among_crcs_is_damage_not_a_bag_without_crcs(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    chunks = [pos for pos, opcode in _records(bytes(data), 8) if opcode == 0x06]
    assert len(chunks) >= 2
    data[chunks[0] + 33 : chunks[0] + 37] = bytes(4)  # its uncompressed_crc
    mcap.write_bytes(bytes(data))
    with open_bag(str(bag)) as reader:
        text = format_bag_info(reader.info)
    assert (
        f"MCAP chunk CRC-32s, except the chunk at byte offset {chunks[0]} of ep.mcap: its CRC field" in text
    )
    assert "written with CRCs off" not in text and "Fix: " not in text


def _mcap_of_profile(path: Path, profile: str, encoding: str) -> Path:
    """One std_msgs/String message in an MCAP file written by the mcap library with ``profile``."""
    from mcap.writer import Writer  # noqa: PLC0415 - only these tests write MCAP without rosbag2's plugin

    with path.open("wb") as handle:
        writer = Writer(handle)
        writer.start(profile=profile, library="test")
        schema_encoding = "ros1msg" if encoding == "ros1" else "ros2msg"
        schema = writer.register_schema(
            name="std_msgs/msg/String", encoding=schema_encoding, data=b"string data"
        )
        channel = writer.register_channel(topic="/s", message_encoding=encoding, schema_id=schema)
        writer.add_message(
            channel, log_time=1, data=b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00", publish_time=1
        )
        writer.finish()  # type: ignore[no-untyped-call]
    return path


@pytest.mark.parametrize(
    ("profile", "encoding", "said", "fix"),
    [
        ("ros1", "ros1", "holds ROS 1 messages (header profile 'ros1'", "convert the original .bag file"),
        (
            "",
            "cdr",
            "is not a rosbag2 MCAP file: its header profile is '', not 'ros2'",
            "Writer.start(profile='ros2')",
        ),
    ],
    ids=["ros1", "empty"],
)
def test_an_mcap_of_another_profile_is_named_as_such_not_as_damage(
    tmp_path: Path, profile: str, encoding: str, said: str, fix: str
) -> None:
    """rosbags refuses these with "Profile is not ros2", which bagport used to report as damaged bytes to
    copy again; what the file is, and what to convert instead, is said."""
    path = _mcap_of_profile(tmp_path / "other.mcap", profile, encoding)
    assert header_profile(path) == profile
    with pytest.raises(BagReadError) as caught:
        open_bag(str(path))
    text = str(caught.value)
    assert f"other.mcap {said}" in text and fix in text, text
    assert "copy the file again" not in text and "the reader said" not in text


def test_a_rosbag2_mcap_names_the_ros2_profile(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.2))
    (data,) = bag.glob("*.mcap")
    assert header_profile(data) == "ros2"
    (tmp_path / "short.mcap").write_bytes(data.read_bytes()[:10])  # no whole header record: not said here
    assert header_profile(tmp_path / "short.mcap") is None
