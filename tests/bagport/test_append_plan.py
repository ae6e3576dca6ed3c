"""Which bags an --append adds (bagport/append_plan.py): another window of a bag in the dataset is a new
episode; the same recording copied again (new modification times) is not appended twice, another
recording under the same name is; one bag written two ways in manifests is one bag."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.errors import DatasetWriteError
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS

SPEC = EpisodeSpec(duration_s=1.5, cameras=SMALL_CAMERAS)


def _append(manifest: Path, out: Path) -> list[str]:
    """Append the manifest's new bags to ``out``; the URIs of the bags the plan adds."""
    config = ConvertConfig(
        manifest=str(manifest),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        encoder=FAST_CODEC,
        append=True,
    )
    plan = plan_run(config)
    added = [r.bag_uri for r in plan.requests] + [e.bag_uri for e in plan.reused]  # reused: staged already
    if added:
        reduce_run(plan, stage_all(plan))
    return added


def _appended_once(tmp_path: Path) -> tuple[Path, Path, Path]:
    """One bag appended to a new dataset: the bag, its manifest and the dataset."""
    bag = tmp_path / "bags" / "ep"
    write_episode_bag(bag, "mcap", SPEC)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n")
    out = tmp_path / "ds"
    assert _append(manifest, out) == [str(bag)]
    return bag, manifest, out


def _episodes(out: Path) -> int:
    return validate_dataset(out, repo_id="test/append", decode_every=30).episodes


def test_another_window_of_a_bag_in_the_dataset_is_appended(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    first = tmp_path / "first.yaml"
    first.write_text(f"bags:\n  - {{uri: {bag}, start_s: 0.0, end_s: 0.75}}\n")
    both = tmp_path / "both.yaml"
    both.write_text(
        f"bags:\n  - {{uri: {bag}, start_s: 0.0, end_s: 0.75}}\n  - {{uri: {bag}, start_s: 0.75, end_s: 1.5}}\n"
    )
    out = tmp_path / "ds"
    assert _append(first, out) == [str(bag)]
    assert _append(both, out) == [str(bag)]  # the second window only
    assert _episodes(out) == 2
    assert _append(both, out) == []  # both windows are in


def test_a_bag_copied_again_is_not_appended_twice_but_another_recording_under_its_name_is(
    tmp_path: Path,
) -> None:
    bag, manifest, out = _appended_once(tmp_path)
    for file in bag.iterdir():  # copied again without keeping times (cp, rsync without -t, a restore)
        os.utime(file, (1_800_000_000, 1_800_000_000))
    assert _append(manifest, out) == []
    assert _episodes(out) == 1
    shutil.rmtree(bag)  # a new recording written under the same name
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=2.0, cameras=SMALL_CAMERAS, seed=5))
    assert _append(manifest, out) == [str(bag)]
    assert _episodes(out) == 2


def test_a_bag_written_another_way_is_the_same_bag(tmp_path: Path) -> None:
    bag, manifest, out = _appended_once(tmp_path)
    for written in (f"file://{bag}", f"{bag}/", f"{bag.parent}/./ep", f"{bag.parent}/../bags/ep"):
        manifest.write_text(f"bags:\n  - uri: '{written}'\n")
        assert _append(manifest, out) == [], written
    assert _episodes(out) == 1


def test_an_append_planned_before_another_run_appended_is_refused_and_its_rerun_adds_only_what_is_new(
    tmp_path: Path,
) -> None:
    """Two appends of the same new bag, overlapping (a manual run beside the hourly ingestion): the one
    that writes second was planned when the bag was new; it is refused, nothing written, and run again it
    finds nothing new."""
    bags = tmp_path / "bags"
    write_episode_bag(bags / "old", "mcap", SPEC)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bags / 'old'}\n")
    out = tmp_path / "ds"
    _append(manifest, out)
    write_episode_bag(bags / "new", "mcap", SPEC)
    manifest.write_text(f"bags:\n  - uri: {bags / 'old'}\n  - uri: {bags / 'new'}\n")
    config = ConvertConfig(
        manifest=str(manifest),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        staging=str(tmp_path / "late.staging"),  # each run its own staging store, as two machines would
        encoder=FAST_CODEC,
        append=True,
    )
    late = plan_run(config)
    assert late.dataset_episodes == 1
    staged = stage_all(late)
    assert _append(manifest, out) == [str(bags / "new")]  # the other run appends it first
    with pytest.raises(
        DatasetWriteError, match=r"changed since this run was planned \(it held 1 episode\(s\), now 2\)"
    ):
        reduce_run(late, staged)
    assert _episodes(out) == 2
    assert _append(manifest, out) == []


def test_an_append_with_other_encoder_settings_is_refused_before_anything_converts(tmp_path: Path) -> None:
    bag, manifest, out = _appended_once(tmp_path)
    write_episode_bag(bag.parent / "new", "mcap", SPEC)
    manifest.write_text(f"bags:\n  - uri: {bag}\n  - uri: {bag.parent / 'new'}\n")
    config = ConvertConfig(
        manifest=str(manifest),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        encoder={**FAST_CODEC, "crf": 28},
        append=True,
    )
    with pytest.raises(
        DatasetWriteError,
        match=r"observation\.images\.\w+ encoder: video\.crf 18 -> 28.*nothing was converted",
    ):
        plan_run(config)
    assert not (out.parent / "ds.staging").exists()  # nothing converted
