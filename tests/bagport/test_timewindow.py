"""The one window type: its key text (part of every staged episode id) and its resolution in a bag."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from bagport.manifest import parse_manifest
from bagport.timewindow import WHOLE_BAG, TimeWindow

BAG_START_NS = 1_700_000_000_000_000_000
BAG_END_NS = BAG_START_NS + 60_000_000_000


def test_the_whole_bag_has_no_key_and_resolves_to_none() -> None:
    assert TimeWindow() == WHOLE_BAG
    assert WHOLE_BAG.is_whole_bag
    assert WHOLE_BAG.key() == ""
    assert WHOLE_BAG.resolve(BAG_START_NS, BAG_END_NS) is None


@pytest.mark.parametrize(
    ("window", "key"),
    [
        (TimeWindow(start_s=1.5, end_s=4.0), "None:None:1.5:4.0"),
        (TimeWindow(end_s=10.0), "None:None:None:10.0"),
        (TimeWindow.of_ns(5, 9), "5:9:None:None"),
        (TimeWindow(start_ns=5, end_s=2.0), "5:None:None:2.0"),
    ],
)
def test_the_key_text_is_the_one_episode_ids_were_made_with(window: TimeWindow, key: str) -> None:
    assert not window.is_whole_bag
    assert window.key() == key  # changing it would change every windowed episode's staged id


def test_seconds_are_from_the_bags_first_message_and_ns_are_absolute() -> None:
    assert TimeWindow(start_s=1.5).resolve(BAG_START_NS, BAG_END_NS) == (
        BAG_START_NS + 1_500_000_000,
        BAG_END_NS,
    )
    assert TimeWindow(end_s=4.0).resolve(BAG_START_NS, BAG_END_NS) == (
        BAG_START_NS,
        BAG_START_NS + 4_000_000_000,
    )
    assert TimeWindow.of_ns(BAG_START_NS + 7, BAG_START_NS + 9).resolve(BAG_START_NS, BAG_END_NS) == (
        BAG_START_NS + 7,
        BAG_START_NS + 9,
    )
    assert TimeWindow(start_ns=BAG_START_NS + 3, end_s=2.0).resolve(BAG_START_NS, BAG_END_NS) == (
        BAG_START_NS + 3,
        BAG_START_NS + 2_000_000_000,
    )


def test_a_manifest_entry_gives_its_window_and_it_crosses_processes(tmp_path: Path) -> None:
    (tmp_path / "a.mcap").touch()
    manifest = parse_manifest(
        "bags:\n  - {uri: a.mcap, start_s: 2, end_s: 3.25}\n  - {uri: a.mcap, start_ns: 10, end_ns: 20}\n",
        "m.yaml",
        base_dir=str(tmp_path),
    )
    windows = [bag.window for bag in manifest.bags]
    assert windows == [TimeWindow(start_s=2.0, end_s=3.25), TimeWindow.of_ns(10, 20)]
    assert [w.key() for w in windows] == ["None:None:2.0:3.25", "10:20:None:None"]
    assert pickle.loads(pickle.dumps(windows)) == windows


def test_a_window_key_reads_back_as_its_window() -> None:
    for window in (
        WHOLE_BAG,
        TimeWindow(start_s=12.5, end_s=47.0),
        TimeWindow(start_s=1.0),
        TimeWindow(start_ns=1_700_000_000_000_000_000, end_ns=1_700_000_005_000_000_000),
        TimeWindow(start_s=0.25, end_ns=1_700_000_005_000_000_000),
    ):
        assert TimeWindow.from_key(window.key()) == window
    assert TimeWindow.from_key(None) is None and TimeWindow.from_key("a:b") is None
    assert TimeWindow.from_key("x:None:None:None") is None


@pytest.mark.parametrize(
    ("a", "b", "overlap"),
    [
        (TimeWindow(start_s=0.0, end_s=10.0), TimeWindow(start_s=5.0, end_s=20.0), True),
        (TimeWindow(start_s=0.0, end_s=10.0), TimeWindow(start_s=10.0, end_s=20.0), False),  # consecutive
        (TimeWindow(start_s=0.0, end_s=10.0), TimeWindow(start_s=11.0), False),
        (TimeWindow(end_s=10.0), TimeWindow(start_s=9.0), True),  # open ends: the bag's start and end
        (WHOLE_BAG, TimeWindow(start_s=3.0, end_s=4.0), True),
        (WHOLE_BAG, TimeWindow(start_ns=3, end_ns=4), True),
        (TimeWindow(start_ns=0, end_ns=10), TimeWindow(start_ns=5, end_ns=6), True),
        (TimeWindow(start_ns=0, end_ns=10), TimeWindow(start_s=0.0, end_s=1.0), None),  # needs the bag
        (TimeWindow(start_s=0.0, end_ns=10), TimeWindow(start_s=0.0, end_s=1.0), None),
        (TimeWindow(start_s=0.0, end_ns=10), WHOLE_BAG, True),  # the whole bag overlaps every window
        (
            TimeWindow.of_ns(BAG_START_NS, BAG_START_NS + 1000),
            TimeWindow.of_ns(BAG_START_NS + 900, BAG_END_NS),
            True,
        ),
    ],
)
def test_two_windows_of_a_bag_overlap_by_more_than_an_instant(
    a: TimeWindow, b: TimeWindow, overlap: bool | None
) -> None:
    assert a.overlaps(b) is overlap and b.overlaps(a) is overlap


def test_a_window_reads_as_a_person_says_it() -> None:
    assert WHOLE_BAG.text() == "the whole bag"
    assert TimeWindow(start_s=12.5, end_s=47.0).text() == "12.5..47 s"
    assert TimeWindow(start_s=3.0).text() == "from 3 s"
    assert TimeWindow(start_ns=5, end_ns=9).text() == "5..9 ns"
    assert TimeWindow(start_s=1.0, end_ns=9).text() == "from 1 s and to 9 ns"
    assert TimeWindow(start_s=12345.61, end_s=13000.0).text() == "12345.61..13000 s"  # as written
