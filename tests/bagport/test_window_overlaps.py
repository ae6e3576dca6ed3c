"""Windows of one bag that overlap: among a manifest's entries, and against the episodes a dataset holds."""

from __future__ import annotations

from bagport.manifest import BagEntry
from bagport.timewindow import WHOLE_BAG, TimeWindow
from bagport.window_overlaps import window_overlaps


def _bag(uri: str, entry: int, window: TimeWindow = WHOLE_BAG) -> BagEntry:
    return BagEntry(uri=uri, entry=entry, window=window)


def _s(start: float | None = None, end: float | None = None) -> TimeWindow:
    return TimeWindow(start_s=start, end_s=end)


def test_entries_of_one_bag_whose_windows_overlap_are_named_once_per_pair() -> None:
    planned = [
        _bag("a", 0, _s(0.0, 10.0)),
        _bag("b", 1),
        _bag("a", 2, _s(10.0, 20.0)),  # after entry 0: no overlap
        _bag("a", 3, _s(15.0, 16.0)),  # inside entry 2
        _bag("b", 4, TimeWindow(start_ns=5, end_ns=6)),  # inside the whole bag of entry 1
        _bag("c", 5, TimeWindow(start_s=1.0, end_ns=9)),  # both clocks: compared with the whole bag only
        _bag("c", 6, _s(0.0, 2.0)),
    ]
    found = window_overlaps(planned)
    assert [(o.uri, o.entry, o.other_entry) for o in found] == [("a", 3, 2), ("b", 4, 1)]
    assert found[0].note() == (
        "bags[3] a: its window 15..16 s overlaps bags[2]'s window 10..20 s: the frames in both are in two "
        "episodes (give each entry its own part of the bag if that is not meant)"
    )
    assert found[1].note().startswith("bags[4] b: its window 5..6 ns overlaps bags[1]'s whole bag:")


def test_a_planned_window_is_compared_with_the_windows_the_dataset_holds_of_its_bag() -> None:
    planned = [_bag("a", 0, _s(5.0, 12.0)), _bag("c", 1, _s(0.0)), _bag("d", 2)]
    held = [
        ("a", _s(0.0, 10.0).key()),  # overlaps
        ("a", _s(12.0, 20.0).key()),  # consecutive: no
        ("a", None),  # an older record: any window, not compared
        ("a", _s(5.0, 12.0).key()),  # the same window: another recording's, not an overlap
        ("c", TimeWindow(start_ns=0, end_ns=10).key()),  # another clock: needs the bag, not compared
        ("d", _s(3.0, 4.0).key()),  # inside the whole bag planned now
        ("z", WHOLE_BAG.key()),  # a bag not planned
    ]
    found = window_overlaps(planned, held)
    assert [(o.uri, o.entry, o.other, o.other_entry) for o in found] == [
        ("a", 0, _s(0.0, 10.0), None),
        ("d", 2, _s(3.0, 4.0), None),
    ]
    assert (
        found[0]
        .note()
        .startswith(
            "bags[0] a: its window 5..12 s overlaps window 0..10 s, which the dataset holds already: the frames"
        )
    )
    assert found[1].note().startswith("bags[2] d: the whole bag overlaps window 3..4 s, which the dataset")


def test_a_whole_bag_a_contract_splits_into_episodes_is_not_compared() -> None:
    """Its windows are the episodes the contract finds, not known before the bag is read."""
    planned = [_bag("a", 0), _bag("a", 1, _s(3.3, 4.4))]
    assert [o.entry for o in window_overlaps(planned)] == [1]
    assert window_overlaps(planned, whole_bag_split=True) == ()
    assert window_overlaps([_bag("a", 1, _s(3.3, 4.4))], [("a", "")], whole_bag_split=True) == ()


def test_thousands_of_windows_of_one_bag_are_compared_in_one_sweep() -> None:
    """10,000 consecutive windows of one bag against 100,000 the dataset holds (an hourly plan): sorted
    once, not compared pairwise (which took 40 s for such a manifest alone); only the real overlaps are
    named: the last entry straddles entries 500 and 501, each entry that overlaps another says so once."""
    planned = [_bag("a", n, _s(float(n), float(n + 1))) for n in range(10_000)]
    planned.append(_bag("a", 10_000, _s(500.5, 501.5)))
    held = [("a", _s(20_000.0 + n, 20_001.0 + n).key()) for n in range(100_000)]
    found = window_overlaps(planned, held)
    assert sorted((o.entry, o.other_entry) for o in found) == [(500, 10_000), (10_000, 501)]
