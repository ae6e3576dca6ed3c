"""Windows of one bag that overlap: among a manifest's entries, and against the episodes a dataset holds."""

from __future__ import annotations

from bagport.manifest import BagEntry
from bagport.timewindow import WHOLE_BAG, TimeWindow
from bagport.window_overlaps import window_overlaps


def _bag(uri: str, entry: int, window: TimeWindow = WHOLE_BAG) -> BagEntry:
    return BagEntry(uri=uri, entry=entry, window=window)


def test_entries_of_one_bag_whose_windows_overlap_are_named_once_each() -> None:
    planned = [
        _bag("a", 0, TimeWindow(start_s=0.0, end_s=10.0)),
        _bag("b", 1),
        _bag("a", 2, TimeWindow(start_s=10.0, end_s=20.0)),  # after entry 0: no overlap
        _bag("a", 3, TimeWindow(start_s=15.0, end_s=16.0)),  # inside entry 2
        _bag("b", 4, TimeWindow(start_ns=5, end_ns=6)),  # inside the whole bag of entry 1
    ]
    found = window_overlaps(planned)
    assert [(o.uri, o.entry, o.other_entry) for o in found] == [("a", 3, 2), ("b", 4, 1)]
    assert found[0].note() == (
        "bags[3] a: its window 15..16 s overlaps bags[2]'s window 10..20 s: the frames in both are in two "
        "episodes (give each entry its own part of the bag if that is not meant)"
    )


def test_a_planned_window_is_compared_with_the_windows_the_dataset_holds_of_its_bag() -> None:
    planned = [_bag("a", 0, TimeWindow(start_s=5.0, end_s=12.0)), _bag("c", 1, TimeWindow(start_s=0.0))]
    held = [
        ("a", TimeWindow(start_s=0.0, end_s=10.0).key()),  # overlaps
        ("a", TimeWindow(start_s=12.0, end_s=20.0).key()),  # consecutive: no
        ("a", None),  # an older record: any window, not compared
        (
            "a",
            TimeWindow(start_s=5.0, end_s=12.0).key(),
        ),  # the same window: a re-recorded bag, not an overlap
        ("c", TimeWindow(start_ns=0, end_ns=10).key()),  # another clock: needs the bag, not compared
        ("z", WHOLE_BAG.key()),  # a bag not planned
    ]
    found = window_overlaps(planned, held)
    assert [(o.uri, o.entry, o.other, o.other_entry) for o in found] == [
        ("a", 0, TimeWindow(start_s=0.0, end_s=10.0), None)
    ]
    assert "the window 0..10 s the dataset holds already" in found[0].note()
