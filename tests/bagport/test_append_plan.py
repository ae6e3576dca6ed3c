"""Which bags an --append adds (bagport/append_plan.py): another window of a bag in the dataset is a new
episode; the same recording copied again (new modification times) is not appended twice, another
recording under the same name is; one bag written two ways in manifests is one bag."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from fsspec.core import url_to_fs

from bagport.config import ConvertConfig
from bagport.dataset.history import dataset_bags
from bagport.dataset.validate import validate_dataset
from bagport.errors import DatasetWriteError
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS
from tests.s3 import moto_s3, s3_bucket

SPEC = EpisodeSpec(duration_s=1.5, cameras=SMALL_CAMERAS)


def _append_config(manifest: Path, out: Path | str) -> ConvertConfig:
    return ConvertConfig(
        manifest=str(manifest),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        encoder=FAST_CODEC,
        append=True,
    )


def _append(manifest: Path, out: Path) -> list[str]:
    """Append the manifest's new bags to ``out``; the URIs of the bags the plan adds."""
    config = _append_config(manifest, out)
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
    assert plan_run(_append_config(both, out)).overlaps == ()  # consecutive windows share an instant only
    assert _append(both, out) == [str(bag)]  # the second window only
    assert _episodes(out) == 2
    assert _append(both, out) == []  # both windows are in


def test_an_edited_window_is_appended_as_another_episode_with_a_warning(tmp_path: Path) -> None:
    """The dataset holds 0..0.75 s of the bag; the manifest now says 0.5..1.5 s: an append adds that window
    as a new episode (it never replaces one) and the plan names the overlap, on the CLI and in the log."""
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - {{uri: {bag}, start_s: 0.0, end_s: 0.75}}\n")
    out = tmp_path / "ds"
    assert _append(manifest, out) == [str(bag)]
    manifest.write_text(f"bags:\n  - {{uri: {bag}, start_s: 0.5, end_s: 1.5}}\n")
    (overlap,) = plan_run(_append_config(manifest, out)).overlaps
    assert overlap.note() == (
        f"bags[0] {bag}: its window 0.5..1.5 s overlaps window 0..0.75 s, which the dataset holds already: the "
        "frames in both are in two episodes. An append adds a window as a new episode and never replaces "
        "one; to change an episode's window, write the dataset again (--overwrite, without --append)"
    )
    assert _append(manifest, out) == [str(bag)]
    assert _episodes(out) == 2
    assert plan_run(_append_config(manifest, out)).overlaps == ()  # said once: nothing new to add now


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
    # each run its own staging store, as two machines would
    config = _append_config(manifest, out).model_copy(update={"staging": str(tmp_path / "late.staging")})
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
    """Other settings of the dataset's codec, or another codec: AV1 onto an H.264 dataset names the codec
    first (the main difference, not its crf), then the pixel format and GOP."""
    bag, manifest, out = _appended_once(tmp_path)
    write_episode_bag(bag.parent / "new", "mcap", SPEC)
    manifest.write_text(f"bags:\n  - uri: {bag}\n  - uri: {bag.parent / 'new'}\n")
    config = _append_config(manifest, out).model_copy(update={"encoder": {**FAST_CODEC, "crf": 28}})
    with pytest.raises(
        DatasetWriteError,
        match=r"observation\.images\.\w+ encoder: video\.crf 18 -> 28.*nothing was converted",
    ):
        plan_run(config)
    # another codec (the dataset is H.264; LeRobot's default, --codec lerobot-default, is AV1): named first
    av1 = {"codec": "libsvtav1", "crf": 30, "preset": 12, "pix_fmt": "yuv420p10le", "g": 4}
    av1_config = config.model_copy(update={"encoder": av1})
    with pytest.raises(DatasetWriteError) as refused:
        plan_run(av1_config)
    camera = (
        "video.codec 'h264' -> 'av1', video.pix_fmt 'yuv420p' -> 'yuv420p10le', video.g 2 -> 4, video.crf 18 -> 30, "
        "video.preset 'ultrafast' -> 12"
    )
    assert (
        f"(observation.images.front encoder: {camera}; observation.images.wrist encoder: {camera}); nothing was "
        "converted" in str(refused.value)
    )
    assert not (out.parent / "ds.staging").exists()  # nothing converted


def _staged(out: Path) -> list[str]:
    episodes = Path(f"{out}.staging") / "episodes"
    return sorted(p.name for p in episodes.iterdir()) if episodes.is_dir() else []


def test_staged_episodes_a_run_killed_after_its_commit_left_are_removed_by_the_next_append(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The kill is a staging clean-up that never ran (tests/flows/test_cli_repair.py kills a real run there);
    a run that kept its staging (``--keep-staging``) keeps it."""
    bag, manifest, out = _appended_once(tmp_path)
    assert _staged(out) == []
    other = tmp_path / "bags" / "other"
    write_episode_bag(other, "mcap", EpisodeSpec(duration_s=1.5, cameras=SMALL_CAMERAS, seed=3))
    manifest.write_text(f"bags:\n  - uri: {bag}\n  - uri: {other}\n")
    with monkeypatch.context() as patched:
        patched.setattr("bagport.reduce._remove_staged", lambda plan, dirs: None)
        assert _append(manifest, out) == [str(other)]
    left = _staged(out)
    assert len(left) == 1 and left[0].startswith("other-")
    assert {staged_id for staged_id, _ in dataset_bags(str(out)).newest_staged} == set(left)
    config = _append_config(manifest, out)
    kept = plan_run(config.model_copy(update={"keep_staging": True}))
    assert kept.staging_removed == () and _staged(out) == left
    summary = Path(f"{out}.staging") / "episodes" / left[0] / "episode.json"
    recorded = summary.read_text()
    summary.write_text(recorded.replace('"source_stamp": "', '"source_stamp": "another-recording-'))
    assert plan_run(config).staging_removed == () and _staged(out) == left  # another recording's: kept
    summary.write_text(recorded)
    plan = plan_run(config)
    assert plan.staging_removed == tuple(left) and not plan.requests and _staged(out) == []
    assert "removed 1 staged episode(s)" in plan.staging_note()
    assert _episodes(out) == 2  # the dataset untouched


def test_a_run_that_kept_its_staging_keeps_it_through_later_appends(tmp_path: Path) -> None:
    bag = tmp_path / "bags" / "ep"
    write_episode_bag(bag, "mcap", SPEC)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"bags:\n  - uri: {bag}\n")
    out = tmp_path / "ds"
    config = _append_config(manifest, out)
    kept = plan_run(config.model_copy(update={"keep_staging": True}))
    reduce_run(kept, stage_all(kept))
    staged = _staged(out)
    assert len(staged) == 1
    known = dataset_bags(str(out))
    assert known.newest_staged == set() and known.committed_staged == set()
    assert plan_run(config).staging_removed == () and _staged(out) == staged


def test_on_an_object_store_the_newest_run_s_staged_episodes_wait_for_a_later_append(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An object store's recovery cannot tell a live write from a dead one, and the newest run may still be
    writing other formats from its staged episodes: its leftovers go once a later run has committed."""
    bags = []
    for seed in range(3):
        bags.append(tmp_path / "bags" / f"ep{seed}")
        write_episode_bag(bags[-1], "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS, seed=seed))
    manifest = tmp_path / "m.yaml"
    with moto_s3() as env:
        s3_bucket(env, "fleet")
        config = _append_config(manifest, "s3://fleet/ds")
        staging = url_to_fs(config.resolved_staging())

        def staged() -> list[str]:
            staging[0].invalidate_cache()
            found = staging[0].glob(f"{staging[1]}/episodes/*/episode.json")
            return sorted(str(p).split("/")[-2] for p in found)

        for n in (1, 2, 3):
            manifest.write_text("bags:\n" + "".join(f"  - uri: {b}\n" for b in bags[:n]))
            with monkeypatch.context() as patched:
                patched.setattr("bagport.reduce._remove_staged", lambda plan, dirs: None)
                plan = plan_run(config)
                reduce_run(plan, stage_all(plan))
            if n == 2:
                assert plan.staging_removed == () and len(staged()) == 2  # the first run's is the newest's
        assert [s.split("-")[0] for s in staged()] == ["ep1", "ep2"]  # the first run's went at the third plan
        final = plan_run(config)
        assert [s.split("-")[0] for s in final.staging_removed] == ["ep1"]
        assert [s.split("-")[0] for s in staged()] == ["ep2"]  # the newest run's waits


def test_windows_of_a_re_recorded_bag_are_not_compared_with_the_old_recording_s(tmp_path: Path) -> None:
    """A new recording under a bag's name is appended again, every window of it: none overlaps the old
    recording's episodes (other frames), so the plan warns of nothing."""
    bag = tmp_path / "bag"
    write_episode_bag(bag, "mcap", SPEC)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(
        f"bags:\n  - {{uri: {bag}, start_s: 0.0, end_s: 0.75}}\n  - {{uri: {bag}, start_s: 0.5}}\n"
    )
    out = tmp_path / "ds"
    plan = plan_run(_append_config(manifest, out))
    assert [o.entry for o in plan.overlaps] == [1]  # the manifest's own two windows overlap
    reduce_run(plan, stage_all(plan))
    shutil.rmtree(bag)
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=2.0, cameras=SMALL_CAMERAS, seed=5))
    plan = plan_run(_append_config(manifest, out))
    assert len(plan.requests) == 2
    assert [(o.entry, o.other_entry) for o in plan.overlaps] == [(1, 0)]  # not against the old recording
    manifest.write_text(f"bags:\n  - {{uri: {bag}, start_s: 0.25, end_s: 1.5}}\n")  # a window of the new one
    plan = plan_run(_append_config(manifest, out))
    assert len(plan.requests) == 1 and plan.overlaps == ()
