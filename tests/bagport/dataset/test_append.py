"""--append: new episodes as new files, old files untouched, meta updated, re-runs add nothing."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.dataset.journal import file_sha256
from bagport.dataset.validate import validate_dataset
from bagport.errors import DatasetWriteError
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bags")
    for i, name in enumerate(("a", "b", "c")):
        spec = EpisodeSpec(duration_s=1.0 + 0.2 * i, seed=i, cameras=SMALL_CAMERAS, task=f"task {name}")
        write_episode_bag(root / name, "mcap", spec)
    return root


def _convert(
    bags: Path,
    names: list[str],
    out: Path,
    *,
    append: bool,
    contract: Path = SAMPLE_CONTRACT,
    reports: list[DatasetReport] | None = None,
) -> int:
    manifest = bags / f"manifest-{'-'.join(names)}.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in names))
    config = ConvertConfig(
        manifest=str(manifest), contract=str(contract), output=str(out), encoder=FAST_CODEC, append=append,
        staging=str(out) + ".staging",
    )  # fmt: skip
    plan = plan_run(config)
    if not plan.requests and not plan.reused:
        return 0
    staged = stage_all(plan)
    report = reduce_run(plan, staged)
    if reports is not None:
        reports.append(report)
    return len(plan.requests) + len(plan.reused)


def _files(root: Path) -> dict[str, tuple[int, int, bytes]]:
    return {
        p.relative_to(root).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns, p.read_bytes())
        for folder in ("data", "videos")
        for p in sorted((root / folder).rglob("*"))
        if p.is_file()
    }


def test_append_adds_new_files_and_keeps_old_ones_byte_identical(bags: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    reports: list[DatasetReport] = []
    assert _convert(bags, ["a", "b"], out, append=True, reports=reports) == 2  # creates a missing dataset
    before = _files(out)
    assert _convert(bags, ["a", "b", "c"], out, append=True, reports=reports) == 1  # only the new bag
    after = _files(out)
    assert {k: after[k] for k in before} == before  # same inode, mtime and bytes
    assert sorted(set(after) - set(before)) == [
        "data/chunk-000/file-001.parquet",
        "videos/observation.images.front/chunk-000/file-001.mp4",
        "videos/observation.images.wrist/chunk-000/file-001.mp4",
    ]
    info = json.loads((out / "meta/info.json").read_text())
    assert (info["total_episodes"], info["total_tasks"], info["splits"]) == (3, 3, {"train": "0:3"})
    assert sorted(p.name for p in (out / "meta/provenance").glob("run*.json")) == ["run-001.json", "run.json"]
    appended = json.loads((out / "meta/provenance/run-001.json").read_text())
    assert [(e["episode_index"], e["bag_uri"].rsplit("/", 1)[-1]) for e in appended["episodes"]] == [(2, "c")]
    qa = json.loads((out / "meta/qa/summary.json").read_text())
    assert [e["episode_index"] for e in qa["episodes"]] == [0, 1, 2]
    assert qa["reports"] == ["report.html"]
    # one report over the whole dataset, rebuilt by each run from the per-run QA index files
    assert [r.qa_report for r in reports] == ["meta/qa/report.html", "meta/qa/report.html"]
    assert sorted(p.name for p in (out / "meta/qa/index").iterdir()) == ["run-000.parquet", "run-001.parquet"]
    assert "over 2 run(s)" in (out / "meta/qa/report.html").read_text()
    report = validate_dataset(out, repo_id="test/append")
    assert report.episodes == 3
    assert report.frames_decoded == info["total_frames"]

    # nothing new: nothing converted, nothing changed
    assert _convert(bags, ["a", "b", "c"], out, append=True) == 0
    assert _files(out) == after


def test_appended_stats_equal_stats_written_in_one_go(bags: Path, tmp_path: Path) -> None:
    appended, whole = tmp_path / "appended", tmp_path / "whole"
    _convert(bags, ["a"], appended, append=True)
    _convert(bags, ["a", "b", "c"], appended, append=True)
    _convert(bags, ["a", "b", "c"], whole, append=False)
    a = json.loads((appended / "meta/stats.json").read_text())
    w = json.loads((whole / "meta/stats.json").read_text())
    assert a.keys() == w.keys()
    for key in w:
        for stat in w[key]:
            np.testing.assert_allclose(
                a[key][stat], w[key][stat], rtol=1e-9, atol=1e-12, err_msg=f"{key}/{stat}"
            )


def test_append_with_other_features_is_refused_and_writes_nothing(bags: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _convert(bags, ["a"], out, append=True)
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    contract = tmp_path / "fewer_joints.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text().replace("position.j5, position.j6]", "position.j5]"))
    with pytest.raises(DatasetWriteError, match="cannot append: the new episodes' features differ"):
        _convert(bags, ["a", "b"], out, append=True, contract=contract)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == before


def test_a_crash_between_the_meta_renames_is_recovered(bags: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _convert(bags, ["a"], out, append=True)
    (out / "meta").rename(out / ".meta.old-deadbeef")  # as if the process died mid-swap
    _convert(bags, ["a", "b"], out, append=True)
    assert not list(out.glob(".meta.old-*"))
    assert json.loads((out / "meta/info.json").read_text())["total_episodes"] == 2
    shutil.rmtree(out.with_name("ds.staging"), ignore_errors=True)


def test_append_to_a_dataset_without_label_columns_keeps_one_episodes_schema(
    bags: Path, tmp_path: Path
) -> None:
    import pyarrow.parquet as pq  # noqa: PLC0415

    out = tmp_path / "ds"
    _convert(bags, ["a"], out, append=True)
    episodes_file = out / "meta/episodes/chunk-000/file-000.parquet"
    older = pq.read_table(episodes_file).drop_columns(["label", "label_note"])  # as bagport wrote it before
    pq.write_table(older, episodes_file)
    record = out / "meta/provenance/run.json"  # and recorded its digest (an append carries digests over)
    files = json.loads(record.read_text())
    files["files"]["meta/episodes/chunk-000/file-000.parquet"] = file_sha256(episodes_file)
    record.write_text(json.dumps(files))
    assert _convert(bags, ["a", "b"], out, append=True) == 1
    assert "label" not in pq.read_schema(out / "meta/episodes/chunk-000/file-001.parquet").names
    assert validate_dataset(out, repo_id="test/append", decode_every=10).episodes == 2


def test_files_an_older_bagport_moved_in_before_it_was_killed_are_removed_before_appending(
    bags: Path, tmp_path: Path
) -> None:
    from bagport.dataset.repair import repair_dataset  # noqa: PLC0415

    out = tmp_path / "ds"
    _convert(bags, ["a"], out, append=True)
    # an append killed after moving its files in, before its meta/ (bagport before the intent record)
    orphans = ["data/chunk-000/file-001.parquet", "videos/observation.images.front/chunk-000/file-001.mp4"]
    for rel in orphans:
        shutil.copy(out / rel.replace("file-001", "file-000"), out / rel)
    assert list(repair_dataset(str(out)).actions) == [
        f"removed {rel}, moved in by an append that was killed before its meta/" for rel in orphans
    ]
    assert _convert(bags, ["a", "b"], out, append=True) == 1
    report = validate_dataset(out, repo_id="test/append", decode_every=10)
    assert report.episodes == 2
    shutil.rmtree(out.with_name("ds.staging"), ignore_errors=True)
