"""--append onto a dataset on S3 (moto's server on loopback, through s3fs): new files only, old ones
untouched, and a crash while publishing leaves readers the previous version until it is rolled back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import s3fs

import bagport.dataset.remote
from bagport.config import ConvertConfig
from bagport.dataset.crashpoints import set_hook
from bagport.dataset.remote import recover_remote
from bagport.dataset.validate import validate_dataset
from bagport.errors import DatasetWriteError, OutputTakenError
from bagport.reduce import reduce_run
from bagport.run import PlannedEpisode, RunPlan, plan_run, stage_all
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT
from tests.s3 import s3_bucket

pytestmark = pytest.mark.slow

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bags")
    for i, name in enumerate(("a", "b")):
        write_episode_bag(
            root / name, "mcap", EpisodeSpec(duration_s=0.6, seed=i, cameras=CAMERAS, task=name)
        )
    return root


@pytest.fixture
def s3(s3_env: dict[str, str]) -> s3fs.S3FileSystem:
    return s3_bucket(s3_env, "fleet")


def _append(bags: Path, names: list[str], output: str, staging: Path) -> int:
    manifest = bags / f"manifest-{'-'.join(names)}.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in names))
    config = ConvertConfig(
        manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output=output, encoder=FAST_CODEC, append=True,
        staging=str(staging),
    )  # fmt: skip
    plan = plan_run(config)
    if plan.requests or plan.reused:
        reduce_run(plan, stage_all(plan))
    return len(plan.requests) + len(plan.reused)


def _etags(fs: s3fs.S3FileSystem, root: str) -> dict[str, str]:
    fs.invalidate_cache()
    return {path[len(root) + 1 :]: str(fs.info(path)["ETag"]) for path in fs.find(root)}


def test_append_on_s3_adds_new_files_and_leaves_old_ones(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    assert _append(bags, ["a"], "s3://fleet/appended", tmp_path / "staging") == 1
    before = _etags(s3, "fleet/appended")
    assert _append(bags, ["a", "b"], "s3://fleet/appended", tmp_path / "staging") == 1  # only the new bag
    after = _etags(s3, "fleet/appended")
    for rel, etag in before.items():
        if rel.startswith(("data/", "videos/")):
            assert after[rel] == etag, rel  # never rewritten
    assert sorted(rel for rel in set(after) - set(before) if not rel.startswith("meta/")) == [
        "data/chunk-000/file-001.parquet",
        "videos/observation.images.front/chunk-000/file-001.mp4",
        "videos/observation.images.wrist/chunk-000/file-001.mp4",
    ]
    assert not [rel for rel in after if rel.startswith(".bagport")]  # no journal or staged files left
    local = tmp_path / "downloaded"
    s3.get("fleet/appended", str(local), recursive=True)
    report = validate_dataset(local, repo_id="test/s3-append")
    assert (report.episodes, report.frames_decoded) == (2, report.frames)
    assert _append(bags, ["a", "b"], "s3://fleet/appended", tmp_path / "staging") == 0  # nothing new


def test_a_crash_while_publishing_on_s3_rolls_back_to_the_previous_version(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _append(bags, ["a"], "s3://fleet/crashed", tmp_path / "staging")
    previous = _etags(s3, "fleet/crashed")
    real_upload = bagport.dataset.remote._upload

    def crash_in_meta(fs: Any, local: Path, remote: str) -> None:
        if "/meta/" in remote and "stats.json" in remote:
            raise KeyboardInterrupt  # the process dies after the data, videos and some of meta/ went up
        real_upload(fs, local, remote)

    monkeypatch.setattr(bagport.dataset.remote, "_upload", crash_in_meta)
    with pytest.raises(KeyboardInterrupt):
        _append(bags, ["a", "b"], "s3://fleet/crashed", tmp_path / "staging")
    crashed = _etags(s3, "fleet/crashed")
    assert ".bagport-journal.json" in crashed
    staged = [rel for rel in crashed if rel.endswith("data/chunk-000/file-001.parquet")]
    assert [rel.split("/")[0][:16] for rel in staged] == [".bagport-staged-"]  # uploaded, but not in data/
    # what a reader sees (everything but bagport's own hidden keys) is the previous version, byte for byte
    assert {k: v for k, v in crashed.items() if not k.startswith(".bagport")} == previous

    monkeypatch.setattr(bagport.dataset.remote, "_upload", real_upload)
    assert recover_remote("s3://fleet/crashed")
    assert _etags(s3, "fleet/crashed") == previous
    assert _append(bags, ["a", "b"], "s3://fleet/crashed", tmp_path / "staging") == 1
    local = tmp_path / "downloaded"
    s3.get("fleet/crashed", str(local), recursive=True)
    assert validate_dataset(local, repo_id="test/s3-crash").episodes == 2


def test_a_crash_while_overwriting_on_s3_rolls_back_and_a_new_write_replaces_stale_files(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _append(bags, ["a", "b"], "s3://fleet/overwritten", tmp_path / "staging")
    previous = _etags(s3, "fleet/overwritten")
    manifest = bags / "manifest-a-only.yaml"
    manifest.write_text("bags:\n  - uri: a\n")
    config = ConvertConfig(
        manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output="s3://fleet/overwritten",
        encoder=FAST_CODEC, staging=str(tmp_path / "staging"), overwrite=True,
    )  # fmt: skip
    plan = plan_run(config)
    staged = stage_all(plan)
    real_upload = bagport.dataset.remote._upload

    def crash_at_info(fs: Any, local: Path, remote: str) -> None:
        if remote.endswith("meta/info.json"):
            raise KeyboardInterrupt
        real_upload(fs, local, remote)

    monkeypatch.setattr(bagport.dataset.remote, "_upload", crash_at_info)
    with pytest.raises(KeyboardInterrupt):
        reduce_run(plan, staged)
    crashed = _etags(s3, "fleet/overwritten")
    assert ".bagport-journal.json" in crashed
    assert {k: v for k, v in crashed.items() if not k.startswith(".bagport")} == previous  # readers: old one
    monkeypatch.setattr(bagport.dataset.remote, "_upload", real_upload)
    plan = plan_run(config)  # planning the next run rolls the crashed one back
    assert _etags(s3, "fleet/overwritten") == previous
    reduce_run(plan, stage_all(plan))
    after = _etags(s3, "fleet/overwritten")
    assert not [rel for rel in after if rel.startswith(".bagport")]
    local = tmp_path / "downloaded"
    s3.get("fleet/overwritten", str(local), recursive=True)
    assert validate_dataset(local, repo_id="test/s3-overwrite").episodes == 1


def test_a_crashed_publish_of_an_older_bagport_is_rolled_back(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    _append(bags, ["a"], "s3://fleet/legacy", tmp_path / "staging")
    previous = _etags(s3, "fleet/legacy")
    # what the journal of bagport before the intent record left: an added file, a rewritten info.json
    s3.copy("fleet/legacy/meta/info.json", "fleet/legacy/.append-backup-0a1b2c3d/meta/info.json")
    s3.pipe_file("fleet/legacy/meta/info.json", b"{}")
    s3.pipe_file("fleet/legacy/data/chunk-000/file-001.parquet", b"half")
    s3.pipe_file(
        "fleet/legacy/.append-journal.json",
        b'{"backup": ".append-backup-0a1b2c3d", "added": ["data/chunk-000/file-001.parquet"], '
        b'"rewritten": ["meta/info.json"], "removed": []}',
    )
    assert recover_remote("s3://fleet/legacy") == [
        "rolled back a publish into fleet/legacy left by an older bagport (its .append-journal.json)"
    ]
    assert _etags(s3, "fleet/legacy") == previous


def _first_write_staged(bags: Path, name: str, staging: Path) -> tuple[RunPlan, list[PlannedEpisode]]:
    """A first write of bag ``a`` to ``s3://fleet/<name>``, planned and staged (not reduced)."""
    (bags / f"manifest-{name}.yaml").write_text("bags:\n  - uri: a\n")
    config = ConvertConfig(
        manifest=str(bags / f"manifest-{name}.yaml"), contract=str(SAMPLE_CONTRACT), output=f"s3://fleet/{name}",
        encoder=FAST_CODEC, staging=str(staging),
    )  # fmt: skip
    plan = plan_run(config)
    return plan, stage_all(plan)


def test_a_first_write_on_s3_never_replaces_a_dataset_another_run_published_meanwhile(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    """Without --overwrite, a dataset that appeared at the output while this run wrote (another run with the
    same --output) is refused at the commit: its objects stay as they are and this run's uploads go."""
    plan, staged = _first_write_staged(bags, "raced", tmp_path / "staging")

    def another_run_publishes(step: str) -> None:
        if step == "s3.files":
            s3.pipe("fleet/raced/meta/info.json", b'{"codebase_version": "v3.0"}')

    set_hook(another_run_publishes)
    try:
        with pytest.raises(OutputTakenError, match="created by another run while this one was writing"):
            reduce_run(plan, staged)
    finally:
        set_hook(None)
    assert sorted(_etags(s3, "fleet/raced")) == ["meta/info.json"]


def test_a_commit_on_s3_whose_uploads_another_run_dropped_publishes_nothing(
    bags: Path, s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    """Without locks, a second run's recovery can drop a live write's staged uploads (two runs with one
    output): the commit checks its files are all there before its commit point, instead of publishing a
    meta/ whose data files do not exist."""
    plan, staged = _first_write_staged(bags, "dropped", tmp_path / "staging")

    def another_run_drops_a_file(step: str) -> None:
        if step == "s3.staged":
            s3.invalidate_cache()
            (data,) = [p for p in s3.find("fleet/dropped") if "/data/" in p]
            s3.rm(data)

    set_hook(another_run_drops_a_file)
    try:
        with pytest.raises(DatasetWriteError, match=r"1 of the \d+ files this run uploaded .* are gone"):
            reduce_run(plan, staged)
    finally:
        set_hook(None)
    assert _etags(s3, "fleet/dropped") == {}  # nothing published, its uploads and record dropped
