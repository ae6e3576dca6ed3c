"""Splitting a bag into episode requests: event topics, done signals, split recordings."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from bagport.bags import open_bag
from bagport.episode import EpisodeRequest, convert_episode
from bagport.segment import segment_request
from bagport.synth import CameraSpec, EpisodeSpec, split_recording, write_episode_bag
from bagport.timewindow import TimeWindow
from tests.helpers import SAMPLE_CONTRACT, episode_request

S = 1_000_000_000
CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)
SPEC = EpisodeSpec(duration_s=6.0, cameras=CAMERAS, joint_rate_hz=50.0)


def _request(bag: Path, episodes: str, staging: Path | None = None) -> EpisodeRequest:
    return episode_request(bag, staging or bag.parent / "staging", SAMPLE_CONTRACT.read_text() + episodes)


def _spans_s(requests: tuple[EpisodeRequest, ...]) -> list[tuple[float, float]]:
    return [
        (
            round(((r.window.start_ns or 0) - SPEC.start_ns) / S, 3),
            round(((r.window.end_ns or 0) - SPEC.start_ns) / S, 3),
        )
        for r in requests
    ]


def test_done_signal_splits_the_bag_at_each_rising_edge(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "bag", "mcap", replace(SPEC, done_at_s=(2.0, 4.0)))
    found = segment_request(_request(tmp_path / "bag", "episodes: {done_signal: {topic: /done}}\n"))
    with open_bag(str(tmp_path / "bag")) as reader:
        bag_start_s, bag_end_s = ((t - SPEC.start_ns) / S for t in (reader.info.start_ns, reader.info.end_ns))
    assert _spans_s(found.requests) == [(bag_start_s, 2.0), (2.0, 4.0), (4.0, round(bag_end_s, 3))]
    assert [r.segment for r in found.requests] == [0, 1, 2]
    assert len({r.episode_id for r in found.requests}) == 3
    assert all(r.label is None for r in found.requests)


def test_events_that_name_no_event_are_reported_and_a_bag_without_events_is_one_episode(
    tmp_path: Path,
) -> None:
    write_episode_bag(tmp_path / "bag", "mcap", replace(SPEC, events=((1.0, "PAUSE"), (2.0, "START"))))
    found = segment_request(_request(tmp_path / "bag", "episodes: {events: {topic: /episode_events}}\n"))
    assert _spans_s(found.requests)[0][0] == 2.0
    assert any("1 message(s) naming no event, first at 1.000 s: 'PAUSE'" in r for r in found.ignored)
    write_episode_bag(tmp_path / "plain", "mcap", SPEC)
    whole = segment_request(_request(tmp_path / "plain", "episodes: {events: {topic: /episode_events}}\n"))
    assert len(whole.requests) == 1
    assert whole.requests[0].segment == 0


def test_a_contract_without_episodes_or_a_manifest_window_keeps_the_request(tmp_path: Path) -> None:
    request = _request(tmp_path / "not-read", "")
    assert segment_request(request).requests == (request,)
    windowed = replace(
        _request(tmp_path / "not-read", "episodes: {gap_s: 1}\n"), window=TimeWindow(start_s=1.0)
    )
    assert segment_request(windowed).requests == (windowed,)


def test_one_episode_spans_the_files_of_a_split_recording(tmp_path: Path) -> None:
    spec = replace(SPEC, duration_s=4.0, events=((0.5, "START"), (3.5, "SUCCESS: across files")))
    write_episode_bag(tmp_path / "whole", "mcap", spec)
    files = split_recording(tmp_path / "whole", tmp_path / "split", [spec.start_ns + 2 * S])
    assert len(files) == 2
    with open_bag(str(tmp_path / "whole")) as whole, open_bag(str(tmp_path / "split")) as split:
        assert split.info.files == ("metadata.yaml", "split_0.mcap", "split_1.mcap")
        assert split.info.message_count == whole.info.message_count
        assert (split.info.start_ns, split.info.end_ns) == (whole.info.start_ns, whole.info.end_ns)
        assert [m.log_time_ns for m in split.messages()] == [m.log_time_ns for m in whole.messages()]
    found = segment_request(_request(tmp_path / "split", "episodes: {events: {topic: /episode_events}}\n"))
    assert _spans_s(found.requests) == [(0.5, 3.5)]
    assert (found.requests[0].label, found.requests[0].note) == ("success", "across files")
    summary = convert_episode(found.requests[0])
    assert summary.window_ns == (found.requests[0].window.start_ns, found.requests[0].window.end_ns)
    first_s = (summary.first_tick_ns - spec.start_ns) / S
    last_s = (summary.last_tick_ns - spec.start_ns) / S
    assert first_s == pytest.approx(0.5, abs=0.05)
    assert 3.4 < last_s <= 3.5  # ticks on both sides of the file boundary at 2 s
    assert summary.frames == pytest.approx((last_s - first_s) * 30 + 1, abs=1)
