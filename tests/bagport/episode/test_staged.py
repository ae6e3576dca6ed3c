"""Which staged episodes a run reuses (one listing, matching keys) and what the current plan puts on them."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import fsspec
import pytest

from bagport.bags import source_stamp
from bagport.episode import convert_episode
from bagport.episode.staged import PlannedEpisode, list_staged, split_staged, staged_with_prefix
from bagport.errors import DatasetWriteError
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import episode_request

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=16, width=16),
    CameraSpec("wrist", "jpeg", height=16, width=16),
)


def test_a_missing_or_empty_staging_store_holds_nothing(tmp_path: Path) -> None:
    assert list_staged(str(tmp_path / "nowhere")) == frozenset()
    (tmp_path / "empty" / "episodes").mkdir(parents=True)
    assert list_staged(str(tmp_path / "empty")) == frozenset()


@pytest.mark.parametrize("store", ["local", "memory"])
def test_staged_episodes_of_a_bag_are_found_by_their_id_prefix(tmp_path: Path, store: str) -> None:
    """Completed ones only (``episode.json`` is written last), and ``bag1-`` is not ``bag10-``."""
    staging = str(tmp_path / "staging") if store == "local" else f"memory://{tmp_path.name}/staging"
    fs, root = fsspec.core.url_to_fs(staging)
    for name, complete in (("bag1-aaa", True), ("bag1-bbb", False), ("bag10-ccc", True), ("bag1-ddd", True)):
        fs.makedirs(f"{root}/episodes/{name}", exist_ok=True)
        fs.pipe(f"{root}/episodes/{name}/{'episode.json' if complete else 'frames.parquet'}", b"{}")
    found = staged_with_prefix(staging, "bag1-")
    assert [uri.rsplit("/", 1)[-1] for uri in found] == ["bag1-aaa", "bag1-ddd"]
    assert all(fsspec.core.url_to_fs(uri)[1].startswith(root) for uri in found)
    assert staged_with_prefix(staging, "bag2-") == []
    assert staged_with_prefix(str(tmp_path / "nowhere"), "bag1-") == []


def test_only_episodes_staged_with_the_same_key_are_reused(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5, cameras=CAMERAS))
    request = episode_request(bag, tmp_path / "staging", task="pick")
    (tmp_path / "staging" / "episodes" / "half-written").mkdir(parents=True)  # no episode.json: not done
    convert_episode(request)
    staged = list_staged(str(tmp_path / "staging"))
    assert staged == {request.episode_id}

    moved = replace(request, manifest_entry=7, metadata={"operator": "bob"})
    split = split_staged([moved], staged, source_stamp)
    assert (split.todo, [e.dir_uri for e in split.reused]) == ((), [PlannedEpisode.of(request).dir_uri])
    assert split.reused[0].reused and split.reused[0].manifest_entry == 7

    other_task = replace(request, default_task="place")  # same episode id, another key
    assert split_staged([other_task], staged, source_stamp).todo == (other_task,)
    data = next(bag.glob("*.mcap"))
    os.utime(data, ns=(data.stat().st_atime_ns, data.stat().st_mtime_ns + 10**9))  # the bag's files changed
    assert split_staged([request], staged, source_stamp).todo == (request,)
    assert split_staged([request], staged, lambda uri: "").todo == (request,)  # no stamp: never reused


def test_the_plan_not_the_staged_record_decides_entry_metadata_and_label(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5, cameras=CAMERAS))
    request = replace(episode_request(bag, tmp_path / "staging"), metadata={"operator": "alice"})
    summary = convert_episode(request)
    planned = PlannedEpisode.of(replace(request, manifest_entry=3, metadata={"operator": "bob"}, note="redo"))
    applied = planned.apply(summary)
    assert (applied.manifest_entry, applied.metadata, applied.note) == (3, {"operator": "bob"}, "redo")
    elsewhere = replace(planned, bag_uri=str(tmp_path / "other"))
    with pytest.raises(DatasetWriteError, match=r"holds .*bag \(segment None\), the plan expects .*other"):
        elsewhere.apply(summary)
