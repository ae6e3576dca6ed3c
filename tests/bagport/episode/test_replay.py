"""A small bag is read once for both passes: what the replay gives is what the bag gives, and a
conversion stages the same episode with it (and the frame table's vectors kept in hand for the stats)
as without (the bag read twice, the table read back)."""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from bagport.bags import BagMessage, BagReader, open_bag
from bagport.episode import convert_episode, replay, sinks
from bagport.episode.replay import ReplayReader, replayable
from bagport.staging import FRAMES_FILE, PROVENANCE_FILE, QA_FILE, STATS_FILE, read_summary
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import episode_request


class _Counting:
    """A reader that counts the reads that reach the bag."""

    def __init__(self, reader: BagReader) -> None:
        self.reader = reader
        self.reads = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.reader, name)

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        self.reads += 1
        return self.reader.messages(topics, start_ns=start_ns, stop_ns=stop_ns)


def _facts(messages: Iterator[BagMessage]) -> list[tuple[str, int, int]]:
    return [(m.topic, m.log_time_ns, m.raw_size) for m in messages]


@pytest.fixture
def bag(tmp_path: Path) -> Path:
    path = tmp_path / "ep"
    write_episode_bag(path, "mcap", EpisodeSpec(duration_s=1.0, seed=5))
    return path


def test_a_covered_read_is_served_from_memory_in_the_bags_order(bag: Path) -> None:
    with open_bag(str(bag)) as whole:
        topics = [t.name for t in whole.info.topics]
        middle_ns = (whole.info.start_ns + whole.info.end_ns) // 2
        direct_all = _facts(whole.messages(topics))
        direct_part = _facts(whole.messages(topics[:2], start_ns=middle_ns, stop_ns=whole.info.end_ns))
        counting = _Counting(whole)
        reader = ReplayReader(counting)
        assert _facts(reader.messages(topics)) == direct_all
        assert (counting.reads, reader.replays) == (1, 1)
        assert _facts(reader.messages(topics)) == direct_all  # again: from memory
        part = _facts(reader.messages(topics[:2], start_ns=middle_ns, stop_ns=whole.info.end_ns))
        assert part == direct_part and part
        assert counting.reads == 1
        _facts(reader.messages(None))  # every topic: not what was kept, so read from the bag
        assert counting.reads == 2


def test_a_windowed_read_of_every_topic_serves_no_wider_read(bag: Path) -> None:
    with open_bag(str(bag)) as whole:
        middle_ns = (whole.info.start_ns + whole.info.end_ns) // 2
        direct_all = _facts(whole.messages(None))
        counting = _Counting(whole)
        reader = ReplayReader(counting)
        window = _facts(reader.messages(None, start_ns=middle_ns))
        assert window and len(window) < len(direct_all) and reader.replays == 1
        assert _facts(reader.messages(None)) == direct_all  # the whole bag: read from the bag again
        assert counting.reads == 2
        later_ns = (middle_ns + whole.info.end_ns) // 2
        assert _facts(reader.messages(None, start_ns=later_ns)) == _facts(
            whole.messages(None, start_ns=later_ns)
        )


def test_an_unfinished_or_too_large_read_is_not_kept(bag: Path) -> None:
    with open_bag(str(bag)) as whole:
        topics = [t.name for t in whole.info.topics]
        counting = _Counting(whole)
        reader = ReplayReader(counting)
        next(iter(reader.messages(topics)))  # stopped after one message
        assert reader.replays == 0
        small = ReplayReader(counting, max_bytes=1000)
        assert len(_facts(small.messages(topics))) == whole.info.message_count
        assert small.replays == 0
        _facts(small.messages(topics))
        assert counting.reads == 3  # each read went to the bag
        assert replayable(whole) is not whole
        big = ReplayReader(counting, max_messages=5)
        _facts(big.messages(topics))
        assert big.replays == 0


def _staged(summary_dir: str) -> dict[str, Any]:
    folder = Path(summary_dir)
    return {
        "frames": pq.read_table(folder / FRAMES_FILE).to_pylist(),
        "provenance": pq.read_table(folder / PROVENANCE_FILE).to_pylist(),
        "qa": json.loads((folder / QA_FILE).read_text()),
        "stats": json.loads((folder / STATS_FILE).read_text()),
        "files": sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")),
    }


def test_conversion_stages_the_same_episode_with_and_without_the_shortcuts(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    replayed = convert_episode(episode_request(bag, tmp_path / "a"))
    monkeypatch.setattr(replay, "REPLAY_MAX_BYTES", 0)  # every bag read twice, as before
    monkeypatch.setattr(sinks.FrameTableWriter, "written_vectors", lambda *_: None)  # the table read back
    monkeypatch.setattr(sinks.FrameTableWriter, "written_table", lambda *_: None)
    read_twice = convert_episode(episode_request(bag, tmp_path / "b"))
    one, two = _staged(replayed.dir_uri), _staged(read_twice.dir_uri)
    assert one == two
    sizes = [read_summary(outcome.dir_uri) for outcome in (replayed, read_twice)]
    assert sizes[0] is not None and sizes[1] is not None
    assert (
        sizes[0].data_bytes == sizes[1].data_bytes and sizes[0].data_bytes
    )  # the table in hand or read back
    assert not any(
        "fidelity" in name or name.endswith(".refs") for name in one["files"]
    )  # scratch not staged
    assert one["qa"]["plots"]["fidelity"]  # the check ran on the written clip
