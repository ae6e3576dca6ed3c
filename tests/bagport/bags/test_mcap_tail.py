"""An MCAP file cut short (a recorder killed, a copy not finished) is said to be one, with where its bytes
end and what is whole, and the fix for it: not "its bytes changed after recording"."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from bagport.bags import open_bag
from bagport.bags.mcap_tail import MAGIC, mcap_cut
from bagport.errors import BagReadError
from tests.helpers import realbag

REAL = "rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap"


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, end) of every record after the leading magic, independently of the code tested."""
    pos, out = len(MAGIC), []
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, opcode, pos + 9 + length))
        pos += 9 + length
        if opcode == 0x0F:  # data end: the summary follows
            break
    return out


@pytest.fixture(scope="module")
def whole() -> bytes:
    return realbag(REAL).read_bytes()


def _cut(tmp_path: Path, data: bytes, size: int) -> Path:
    path = tmp_path / f"cut_{size}.mcap"
    path.write_bytes(data[:size])
    return path


def test_a_whole_file_and_one_that_is_not_mcap_have_no_cut(tmp_path: Path, whole: bytes) -> None:
    assert mcap_cut(realbag(REAL)) is None
    other = tmp_path / "other.mcap"
    other.write_bytes(b"not an mcap file at all")
    assert mcap_cut(other) is None


def test_a_file_cut_inside_a_chunk_names_the_chunk_and_the_whole_ones_before(
    tmp_path: Path, whole: bytes
) -> None:
    chunks = [(at, end) for at, opcode, end in _records(whole) if opcode == 0x06]
    assert len(chunks) >= 2
    second_at, second_end = chunks[1]
    cut = mcap_cut(_cut(tmp_path, whole, (second_at + second_end) // 2))
    assert cut is not None
    assert (cut.record_at, cut.chunks, cut.data_whole) == (second_at, 1, False)
    assert f"inside the record that starts at byte {second_at}" in cut.describe()
    assert "the 1 chunk(s) before are whole" in cut.describe()


def test_a_file_cut_after_its_data_says_only_the_summary_is_missing(tmp_path: Path, whole: bytes) -> None:
    records = _records(whole)
    data_end = next(end for _, opcode, end in records if opcode == 0x0F)
    chunks = sum(opcode == 0x06 for _, opcode, _ in records)
    cut = mcap_cut(_cut(tmp_path, whole, data_end + 10))
    assert cut is not None
    assert (cut.chunks, cut.data_whole) == (chunks, True)
    assert f"its {chunks} chunk(s) of messages are whole" in cut.describe()


def test_opening_a_cut_file_says_it_was_cut_short_with_the_recover_fix(tmp_path: Path, whole: bytes) -> None:
    path = _cut(tmp_path, whole, len(whole) // 2)
    with pytest.raises(BagReadError) as caught:
        open_bag(str(path)).close()
    message = str(caught.value)
    assert f"the file ends at byte {len(whole) // 2}" in message
    assert "cut short" in message
    assert "mcap recover" in message
    assert "changed after recording" not in message
    assert "Error:" not in message  # the storage library's own words are not the diagnosis
