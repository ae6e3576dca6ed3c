"""A bag's segmentation is kept in the staging store: asked again, the bag is not opened; a changed bag,
episodes section or corrupt entry segments it again."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import AbstractContextManager
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from bagport.bags import BagReader, open_bag
from bagport.episode import EpisodeRequest
from bagport.segment import segment_request
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import SAMPLE_CONTRACT, episode_request

SPEC = EpisodeSpec(
    duration_s=5.0,
    cameras=(CameraSpec("front", "raw", "bgr8", height=16, width=16),),
    events=((0.5, "START"), (2.0, "SUCCESS"), (2.5, "START"), (4.5, "FAIL: slipped")),
)
EVENTS = "episodes: {events: {topic: /episode_events}}\n"


@pytest.fixture
def opened(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The URIs of the bags segmentation opens, in order."""
    calls: list[str] = []

    def counting(uri: str, **options: Any) -> AbstractContextManager[BagReader]:
        calls.append(uri)
        return open_bag(uri, **options)

    monkeypatch.setattr("bagport.segment.scan.open_bag", counting)
    return calls


def _request(bag: Path, episodes: str = EVENTS, **encoder: Any) -> EpisodeRequest:
    return episode_request(
        bag, bag.parent / "staging", SAMPLE_CONTRACT.read_text() + episodes, encoder=encoder or None
    )


def _entries(bag: Path) -> Iterator[Path]:
    return (bag.parent / "staging" / "segments").glob("*.json")


def test_a_second_segmentation_of_the_same_bag_does_not_open_it(tmp_path: Path, opened: list[str]) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    first = segment_request(_request(bag))
    assert [(r.label, r.note) for r in first.requests] == [("success", ""), ("failed", "slipped")]
    assert not first.cached
    assert opened == [str(bag)]
    again = segment_request(_request(bag))
    assert again == replace(first, cached=True)
    assert opened == [str(bag)]  # not opened the second time
    # what does not change the windows does not segment again; the requests follow the new request
    other_codec = segment_request(_request(bag, crf=40))
    assert other_codec.cached
    assert other_codec.requests == tuple(
        _request(bag, crf=40).for_window(k, r.window, r.label, r.note) for k, r in enumerate(first.requests)
    )
    assert len(opened) == 1


def test_a_changed_episodes_section_or_bag_segments_again(tmp_path: Path, opened: list[str]) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    segment_request(_request(bag))
    longer = segment_request(_request(bag, EVENTS.replace("}}", "}, min_duration_s: 1.8}")))
    assert not longer.cached
    assert [r.label for r in longer.requests] == ["failed"]  # the 1.5 s success is now too short
    assert len(opened) == 2
    shutil.rmtree(bag)  # re-recorded: one demonstration only
    write_episode_bag(bag, "mcap", replace(SPEC, events=((0.5, "START"), (4.0, "SUCCESS"))))
    rerecorded = segment_request(_request(bag))
    assert not rerecorded.cached
    assert [r.label for r in rerecorded.requests] == ["success"]
    assert opened == [str(bag)] * 3
    assert segment_request(_request(bag)).cached


@pytest.mark.parametrize("content", ["", '{"format": 1, "windows": [{"start_ns": 1', '{"x": 1}', "[]"])
def test_an_unreadable_entry_is_ignored_and_rewritten(
    tmp_path: Path, opened: list[str], content: str
) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    first = segment_request(_request(bag))
    (entry,) = _entries(bag)
    entry.write_text(content)
    again = segment_request(_request(bag))
    assert again == first
    assert len(opened) == 2
    assert segment_request(_request(bag)).cached  # rewritten


def test_without_a_staging_store_nothing_is_kept(
    tmp_path: Path, opened: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    monkeypatch.chdir(tmp_path)
    qa_request = replace(_request(bag), staging_uri="")  # as `bagport qa` asks
    assert not segment_request(qa_request).cached
    assert not segment_request(qa_request).cached
    assert len(opened) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no `segments/` in the working folder
