"""A ROS 1 bag cut short (a `rosbag record` killed, a copy not finished) is said to be one, with where its
bytes end, how many are missing and what is whole, and the fix for it (copy it again, else `rosbag reindex`
keeps the whole chunks): not "record damaged: data length N runs past the end"."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from bagport.bags import open_bag
from bagport.bags.ros1_tail import ros1_cut
from bagport.episode import convert_episode
from bagport.errors import BagportError, BagReadError
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import main
from tests.helpers import SMALL_CAMERAS, episode_request

SPEC = EpisodeSpec(duration_s=6.0, cameras=SMALL_CAMERAS)


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, op, end) of every top-level record after the version line, independently of the code tested."""
    pos, out = 13, []
    while pos < len(data):
        (header_len,) = struct.unpack_from("<I", data, pos)
        header = data[pos + 4 : pos + 4 + header_len]
        (data_len,) = struct.unpack_from("<I", data, pos + 4 + header_len)
        op = header[header.index(b"op=") + 3]
        out.append((pos, op, pos + 8 + header_len + data_len))
        pos += 8 + header_len + data_len
    return out


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    bag = tmp_path_factory.mktemp("whole") / "ep.bag"
    write_episode_bag(bag, "ros1", SPEC)
    return bag.read_bytes()


def _cut(tmp_path: Path, data: bytes, size: int, *, unclosed: bool = False) -> Path:
    """The bag's first ``size`` bytes; ``unclosed``: its header's index_pos 0, as a killed recorder leaves it."""
    head = bytearray(data[:size])
    if unclosed:
        at = head.index(b"index_pos=") + len(b"index_pos=")
        head[at : at + 8] = bytes(8)
    path = tmp_path / "ep.bag"
    path.write_bytes(bytes(head))
    return path


def _chunks(data: bytes) -> list[tuple[int, int]]:
    return [(at, end) for at, op, end in _records(data) if op == 0x05]


def test_a_whole_bag_and_one_that_is_not_ros1_have_no_cut(tmp_path: Path, whole: bytes) -> None:
    assert ros1_cut(_cut(tmp_path, whole, len(whole))) is None
    other = tmp_path / "other.bag"
    other.write_bytes(b"not a bag at all" * 100)
    assert ros1_cut(other) is None


def test_a_bag_cut_inside_a_chunk_names_the_chunk_the_missing_bytes_and_the_whole_ones(
    tmp_path: Path, whole: bytes
) -> None:
    chunks = _chunks(whole)
    assert len(chunks) >= 3
    second_at, second_end = chunks[1]
    size = (second_at + second_end) // 2
    cut = ros1_cut(_cut(tmp_path, whole, size))
    assert cut is not None
    assert (cut.record_at, cut.missing, cut.chunks, cut.data_whole) == (
        second_at,
        second_end - size,
        1,
        False,
    )
    said = cut.describe()
    assert f"the file ends at byte {size}, inside the record that starts at byte {second_at}" in said
    assert f"{second_end - size} bytes short of its end" in said and "a copy or download" in said
    assert said.endswith("; the 1 chunk(s) of messages before it are whole")
    fix = cut.fix()
    assert fix.startswith(
        "if the recording is whole on the robot, copy it again; else `rosbag reindex ep.bag`"
    )
    assert "keeps the 1 whole chunk(s) before the cut" in fix and "ep.orig.bag" in fix


def test_a_killed_recorder_is_told_by_its_header_index_pos_0(tmp_path: Path, whole: bytes) -> None:
    third_at = _chunks(whole)[2][0]
    cut = ros1_cut(_cut(tmp_path, whole, third_at + 100, unclosed=True))
    assert cut is not None and (cut.index_at, cut.chunks, cut.record_at) == (0, 2, third_at)
    assert "the recorder stopped before closing the bag: its header's index_pos is 0" in cut.describe()


@pytest.mark.parametrize("where", ["chunk-index", "index-section"])
def test_a_bag_cut_in_its_index_loses_no_message(tmp_path: Path, whole: bytes, where: str) -> None:
    """After its last chunk come that chunk's index records, then (at index_pos) the index section."""
    chunks = _chunks(whole)
    records = _records(whole)
    last = next(i for i, (at, _, _) in enumerate(records) if at == chunks[-1][0])
    at = records[last + 1][0] if where == "chunk-index" else next(r[0] for r in records if r[1] == 0x06)
    cut = ros1_cut(_cut(tmp_path, whole, at + 20))
    assert cut is not None and cut.data_whole and (cut.chunks, cut.record_at) == (len(chunks), at)
    said = cut.describe()
    assert (
        f"after all its {len(chunks)} chunk(s) of messages, inside the record that starts at byte {at}"
        in said
    )
    assert said.endswith("no message is lost")
    assert f"rebuilds its index from its {len(chunks)} whole chunk(s), losing no message" in cut.fix()


def test_a_bag_cut_at_a_record_boundary_before_its_index_is_cut(tmp_path: Path, whole: bytes) -> None:
    """A closed bag whose bytes end between records, before the index its header points at."""
    second_end = _chunks(whole)[1][1]
    cut = ros1_cut(_cut(tmp_path, whole, second_end))
    assert cut is not None and (cut.record_at, cut.missing, cut.chunks) == (None, None, 2)
    assert "between records, before the index its header places at byte" in cut.describe()
    # never closed and ending between records, it is an unindexed bag (rosbags says so, reindex reads it)
    assert ros1_cut(_cut(tmp_path, whole, second_end, unclosed=True)) is None


def test_a_bag_cut_before_its_first_chunk_is_whole_says_only_a_copy_helps(
    tmp_path: Path, whole: bytes
) -> None:
    for size in (20, 3000):  # inside the bag header's fields, inside its padding
        cut = ros1_cut(_cut(tmp_path, whole, size))
        assert cut is not None and cut.chunks == 0 and cut.record_at == 13
        assert "no chunk of messages before it is whole" in cut.describe()
        assert cut.fix().startswith("copy the bag again from the robot or a backup: no chunk")


def _assert_cut_message(message: str, size: int) -> None:
    assert f"ep.bag: the file ends at byte {size}, inside the record that starts at byte " in message, message
    assert "cut short" in message and "Fix: if the recording is whole on the robot" in message, message
    assert "`rosbag reindex ep.bag` keeps the 1 whole chunk(s)" in message, message
    assert "runs past the end" not in message and "record damaged" not in message, message
    assert "Error" not in message and "Traceback" not in message, message


@pytest.mark.parametrize("unclosed", [False, True], ids=["copy-cut", "recorder-killed"])
def test_opening_or_converting_a_cut_bag_says_it_was_cut_short(
    tmp_path: Path, whole: bytes, unclosed: bool
) -> None:
    second_at, second_end = _chunks(whole)[1]
    size = (second_at + second_end) // 2
    bag = _cut(tmp_path, whole, size, unclosed=unclosed)
    for attempt in (
        lambda: open_bag(str(bag)).close(),
        lambda: convert_episode(episode_request(bag, tmp_path / "s")),
    ):
        with pytest.raises(BagportError) as caught:
            attempt()
        assert isinstance(caught.value, BagReadError), str(caught.value)
        assert caught.value.fix is not None and caught.value.fix.startswith("if the recording is whole")
        _assert_cut_message(str(caught.value), size)


def test_inspect_of_a_cut_bag_says_it_was_cut_short(
    tmp_path: Path, whole: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    size = _chunks(whole)[1][0] + 5000
    bag = _cut(tmp_path, whole, size)
    assert main(["inspect", str(bag)]) == 2
    _assert_cut_message(capsys.readouterr().err, size)
