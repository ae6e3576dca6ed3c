"""Bit flips at chosen offsets of a chunked MCAP with CRCs and of a SQLite bag: each is refused with one
paragraph naming the damage, or converts identically to the undamaged bag when the flip touched nothing
the contract reads. A flip inside a SQLite message's value is undetectable (the format has no checksum):
it converts into a different value, and the episode's QA says the bag carries no checksums."""

from __future__ import annotations

import re
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from bagport.bags import open_bag
from bagport.columns import vector_column
from bagport.episode import convert_episode
from bagport.errors import BagportError
from bagport.staging import EpisodeSummary
from bagport.synth import EpisodeSpec, write_episode_bag
from bagport.video import iter_frames
from tests.helpers import REPO, SAMPLE_CONTRACT, SMALL_CAMERAS, episode_request

SPEC = EpisodeSpec(duration_s=1.5, cameras=SMALL_CAMERAS, mcap_crcs=True)
Offset = Callable[[bytes, Path], int]
"""Where to flip, from the data file's bytes and the bag folder."""


def _mcap_chunks(folder: Path) -> list[tuple[int, int]]:
    with (folder / "ep.mcap").open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


def _sqlite_payload_at(folder: Path, row: int, data: bytes) -> int:
    with sqlite3.connect(folder / "ep.db3") as db:
        payload = db.execute(f"SELECT data FROM messages WHERE id = {row}").fetchone()[0]
    return data.index(payload)


def _sqlite_messages_page(folder: Path, data: bytes) -> int:
    page_size = int.from_bytes(data[16:18], "big")
    return _sqlite_payload_at(folder, 60, data) // page_size * page_size


def _sqlite_free_space(_: Path, data: bytes) -> int:
    """A byte of the unallocated gap between a leaf page's cell pointers and its cells."""
    page_size = int.from_bytes(data[16:18], "big")
    for start in range(page_size, len(data), page_size):
        cells, content = (
            int.from_bytes(data[start + 3 : start + 5], "big"),
            int.from_bytes(data[start + 5 : start + 7], "big"),
        )
        gap = start + 8 + 2 * cells
        if data[start] == 0x0D and content - (8 + 2 * cells) > 32:
            return gap + 16
    raise AssertionError("no leaf page with free space")


# (case, storage, where to flip, expected: a regex of the refusal, or None for an identical conversion)
CASES: list[tuple[str, str, Offset, str | None]] = [
    ("mcap-first-chunk", "mcap", lambda d, f: _mcap_chunks(f)[0][0] + 300, r"ep\.mcap at byte offset {chunk0}: chunk fails its CRC-32"),
    ("mcap-middle-chunk", "mcap", lambda d, f: sum(_mcap_chunks(f)[len(_mcap_chunks(f)) // 2]) - 50, r"reading failed: ep\.mcap at byte offset \d+: chunk fails its CRC-32 check"),
    ("mcap-crc-field", "mcap", lambda d, f: _mcap_chunks(f)[-1][0] + 33, r"ep\.mcap at byte offset \d+: chunk fails its CRC-32 check"),
    ("mcap-header-library", "mcap", lambda d, f: d.index(b"rosbags-") + 3, None),
    ("mcap-message-index", "mcap", lambda d, f: sum(_mcap_chunks(f)[0]) + 9 + 2 + 4 + 3, None),
    ("sqlite-file-header", "sqlite3", lambda d, f: 16, r"ep\.db3"),
    ("sqlite-page-type", "sqlite3", lambda d, f: _sqlite_messages_page(f, d), r"ep\.db3 at byte offset \d+: page \d+ of messages has a damaged b-tree header"),
    ("sqlite-record-header", "sqlite3", lambda d, f: _sqlite_payload_at(f, 40, d) - 12, r"ep\.db3: (message row 40 holds a \w+ timestamp|the message row after row 3\d \(on /\S+\) cannot be read)"),
    ("sqlite-free-space", "sqlite3", lambda d, f: _sqlite_free_space(f, d), None),
]  # fmt: skip


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, EpisodeSummary]]:
    """Each format's undamaged bag and its conversion."""
    root = tmp_path_factory.mktemp("clean")
    out = {}
    for storage in ("mcap", "sqlite3"):
        bag = root / storage / "ep"
        write_episode_bag(bag, storage, SPEC)
        out[storage] = (bag, convert_episode(episode_request(bag, root / f"staging-{storage}")))
    return out


def _damaged_copy(source: Path, target: Path, offset: Offset) -> tuple[Path, int]:
    shutil.copytree(source, target)
    (data_file,) = (p for p in target.iterdir() if p.suffix in (".mcap", ".db3"))
    data = bytearray(data_file.read_bytes())
    at = offset(bytes(data), target)
    data[at] ^= 0x10
    data_file.write_bytes(bytes(data))
    return target, at


def _same_episode(a: EpisodeSummary, b: EpisodeSummary) -> None:
    assert pq.read_table(Path(a.dir_uri) / "frames.parquet").equals(
        pq.read_table(Path(b.dir_uri) / "frames.parquet")
    )
    for key, clip in a.videos.items():
        frames_a = list(iter_frames(Path(a.dir_uri) / clip))
        frames_b = list(iter_frames(Path(b.dir_uri) / b.videos[key]))
        assert len(frames_a) == len(frames_b) == a.frames
        for (pts_a, rgb_a), (pts_b, rgb_b) in zip(frames_a, frames_b, strict=True):
            assert pts_a == pts_b and np.array_equal(rgb_a, rgb_b), key


@pytest.mark.parametrize(("case", "storage", "offset", "refusal"), CASES, ids=[c[0] for c in CASES])
def test_a_bit_flip_is_refused_naming_the_damage_or_changes_nothing(
    clean: dict[str, tuple[Path, EpisodeSummary]],
    tmp_path: Path,
    case: str,
    storage: str,
    offset: Offset,
    refusal: str | None,
) -> None:
    bag, reference = clean[storage]
    damaged, at = _damaged_copy(bag, tmp_path / case / "ep", offset)
    request = episode_request(damaged, tmp_path / "staging")
    if refusal is None:
        _same_episode(convert_episode(request), reference)
        return
    with pytest.raises(BagportError) as caught:
        convert_episode(request)
    text = str(caught.value)
    assert "\n" not in text and "Fix: " in text and str(damaged) in text, text
    pattern = refusal.format(chunk0=_mcap_chunks(bag)[0][0]) if storage == "mcap" else refusal
    assert re.search(pattern, text), f"flip at byte {at}: {text}"
    assert not list((tmp_path / "staging").glob("*/*/episode.json"))  # nothing staged


def test_a_flip_in_a_sqlite_value_is_undetectable_and_the_episode_says_so(
    clean: dict[str, tuple[Path, EpisodeSummary]], tmp_path: Path
) -> None:
    bag, reference = clean["sqlite3"]
    provenance = pq.read_table(Path(reference.dir_uri) / "provenance.parquet").to_pylist()
    used_ns = next(
        r["source_log_ns"] for r in provenance if r["key"] == "observation.state" and r["frame_index"] == 20
    )
    with sqlite3.connect(bag / "ep.db3") as db:
        (row,) = db.execute(
            "SELECT messages.id FROM messages JOIN topics ON topics.id = topic_id "
            "WHERE topics.name = '/joint_states' AND timestamp = ?",
            (used_ns,),
        ).fetchone()
    with open_bag(str(bag)) as reader:
        message = next(m for m in reader.messages(["/joint_states"]) if m.log_time_ns == used_ns)
        j1 = np.float64(message.msg().position[list(message.msg().name).index("j1")]).tobytes()

    def value_byte(data: bytes, folder: Path) -> int:
        at = _sqlite_payload_at(folder, row, data)
        return data.index(j1, at) + 6  # the exponent of j1's position: a different, plausible number

    damaged, _ = _damaged_copy(bag, tmp_path / "ep", value_byte)
    summary = convert_episode(episode_request(damaged, tmp_path / "staging"))
    ours = vector_column(pq.read_table(Path(summary.dir_uri) / "frames.parquet"), "observation.state")
    theirs = vector_column(pq.read_table(Path(reference.dir_uri) / "frames.parquet"), "observation.state")
    assert np.flatnonzero((ours != theirs).any(axis=1)).tolist() == [20]  # a different value, unseen
    assert summary.qa["verdict"] == "warn"
    assert "integrity.unchecked" in [p["check"] for p in summary.qa["problems"]]


@pytest.mark.slow
def test_the_cli_reports_a_damaged_sqlite_row_without_a_traceback(tmp_path: Path) -> None:
    """The issue's case ("Task run encountered an exception TypeError: object of type 'int' has no len()")
    through `bagport convert`, in a fresh process as a user runs it."""
    bag = tmp_path / "ep"
    write_episode_bag(bag, "sqlite3", replace(SPEC, duration_s=1.0))
    with sqlite3.connect(bag / "ep.db3") as db:
        db.execute("UPDATE messages SET data = 12345 WHERE id = 30")
    (tmp_path / "m.yaml").write_text("bags:\n  - uri: ep\n")
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--manifest", str(tmp_path / "m.yaml"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "out"), "--runner", "thread",
    ]  # fmt: skip
    proc = subprocess.run(command, capture_output=True, text=True, check=False, cwd=REPO)
    assert "Traceback" not in proc.stderr and "TypeError" not in proc.stderr, proc.stderr
    assert proc.returncode in (1, 2), proc.stderr
    assert re.search(
        r"the message record on /\S+ after log time \d+ ns is damaged: its payload is a int", proc.stderr
    )
    assert not (tmp_path / "out").exists()
