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


def test_damage_bagport_cannot_locate_quotes_the_reader(tmp_path: Path) -> None:
    bag, mcap = _bag(tmp_path, CRCS)
    data = bytearray(mcap.read_bytes())
    data[17:21] = bytes(4)  # the header's profile: "" (no framing damage: its length still fits)
    mcap.write_bytes(bytes(data))
    with pytest.raises(
        BagReadError, match=r"cannot be opened; the reader said: AnyReaderError: Profile is not"
    ):
        open_bag(str(bag))


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
