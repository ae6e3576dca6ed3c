"""The QA policy in the reduce step: exclude (default), keep and flag, or fail the run."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from s3fs import S3FileSystem

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.episode import convert_episode
from bagport.errors import BagportError, DatasetWriteError, EncoderSettingsError, QualityError
from bagport.reduce import finish_up_to_date, reduce_run
from bagport.run import EpisodeFailure, PlannedEpisode, RunPlan, plan_run, stage_all
from bagport.synth import EpisodeSpec, Faults, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three bags: clean, NaN joints (fails QA), clean."""
    root = tmp_path_factory.mktemp("fleet")
    spec = EpisodeSpec(
        duration_s=2.5, cameras=SMALL_CAMERAS, mcap_crcs=True
    )  # checksummed: verdicts stay "pass"
    for name, faults in (("a", Faults()), ("nan", Faults(joint_nan_at_s=1.0)), ("c", Faults())):
        write_episode_bag(root / name, "mcap", replace(spec, faults=faults))
    (root / "manifest.yaml").write_text("bags:\n  - uri: a\n  - uri: nan\n  - uri: c\n")
    return root


def _run(fleet: Path, out: Path, **options: object) -> tuple[ConvertConfig, list[PlannedEpisode]]:
    config = ConvertConfig(
        manifest=str(fleet / "manifest.yaml"),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        staging=str(fleet / "staging"),
        encoder=FAST_CODEC,
        keep_staging=True,
        **options,  # type: ignore[arg-type]
    )
    plan = plan_run(config)
    return config, stage_all(plan)


def test_failing_episode_is_excluded_and_listed_with_its_reason(fleet: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    config, staged = _run(fleet, out)
    report = reduce_run(plan_run(config), staged)
    assert report.episodes == 2
    assert [row.bag_uri.rsplit("/", 1)[-1] for row in report.excluded] == ["nan"]
    assert "values.non_finite observation.state" in report.excluded[0].reason
    summary = json.loads((out / "meta/qa/summary.json").read_text())
    assert [(e["episode_index"], e["verdict"]) for e in summary["episodes"]] == [
        (0, "pass"),
        (None, "fail"),
        (1, "pass"),
    ]
    table = pq.read_table(out / "meta/qa/chunk-000/file-000.parquet").to_pylist()
    failing = [r for r in table if r["verdict"] == "fail"]
    assert {(r["check"], r["excluded"], r["episode_index"]) for r in failing} == {
        ("values.non_finite", True, None)
    }
    run = json.loads((out / "meta/provenance/run.json").read_text())
    assert [e["qa"]["verdict"] for e in run["episodes"]] == ["pass", "pass"]
    assert run["excluded"][0]["manifest_entry"] == 1
    assert "<html>" in (out / "meta/qa/report.html").read_text()
    validated = validate_dataset(out, repo_id="test/qa", decode_every=10)
    assert validated.episodes == 2


def test_keep_flags_the_failing_episode_in_the_dataset(fleet: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    config, staged = _run(fleet, out, on_qa_fail="keep")
    report = reduce_run(plan_run(config), staged)
    assert (report.episodes, report.excluded) == (3, ())
    summary = json.loads((out / "meta/qa/summary.json").read_text())
    assert [(e["episode_index"], e["verdict"]) for e in summary["episodes"]] == [
        (0, "pass"),
        (1, "fail"),
        (2, "pass"),
    ]


def test_fail_run_writes_nothing_and_lists_failures(fleet: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    config, staged = _run(fleet, out, on_qa_fail="fail_run")
    failure = EpisodeFailure(str(fleet / "gone"), 3, "gone: bag does not exist")
    with pytest.raises(QualityError, match=r"(?s)2 of 4 bag\(s\) failed.*nothing was written") as info:
        reduce_run(plan_run(config), staged, [failure])
    assert "bags[1]" in str(info.value)
    assert "values.non_finite" in str(info.value)
    assert "bags[3]" in str(info.value)
    assert not out.exists()


def test_a_bag_that_failed_to_convert_is_excluded_with_its_error(fleet: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    config, staged = _run(fleet, out)
    failure = EpisodeFailure(str(fleet / "gone"), 3, "gone: bag does not exist")
    report = reduce_run(plan_run(config), staged, [failure])
    assert [r.reason for r in report.excluded][-1] == "conversion failed: gone: bag does not exist"


def test_nothing_left_is_an_error_that_says_how_to_fix_it(fleet: Path, tmp_path: Path) -> None:
    config, staged = _run(fleet, tmp_path / "ds")
    with pytest.raises(QualityError, match=r"(?s)no episode is left to write.*--on-qa-fail keep"):
        reduce_run(plan_run(config), staged[1:2])


def test_nothing_left_after_conversion_errors_points_at_them_not_at_qa_settings(
    fleet: Path, tmp_path: Path
) -> None:
    """No QA setting keeps a bag that failed to convert: the fix is the error's own (a contract's topic
    typo fails every bag the same way, and --on-qa-fail keep would change nothing)."""
    config, _ = _run(fleet, tmp_path / "ds")
    failure = EpisodeFailure(str(fleet / "gone"), 3, "gone: bag does not exist")
    with pytest.raises(QualityError) as info:
        reduce_run(plan_run(config), [], [failure])
    text = str(info.value)
    assert "conversion failed: gone: bag does not exist" in text
    assert "correct what each conversion error above names" in text and "--on-qa-fail" not in text


def test_a_broken_bag_arriving_alone_is_recorded_excluded_and_not_retried(tmp_path: Path) -> None:
    """Finding 4 of issue 16: an append whose only new bag fails records the exclusion (the next
    scheduled run skips the unchanged bag) instead of failing with "no episode is left"."""
    bags = tmp_path / "bags"
    write_episode_bag(bags / "good", "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS))
    out = tmp_path / "ds"
    options = {"bags_glob": str(bags / "*"), "contract": str(SAMPLE_CONTRACT), "output": str(out)}
    config = ConvertConfig(**options, encoder=FAST_CODEC, append=True)  # type: ignore[arg-type]
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    (bags / "broken.mcap").write_bytes(b"not a bag at all")
    plan = plan_run(config)
    assert [Path(r.bag_uri).name for r in plan.requests] == ["broken.mcap"]
    failure = EpisodeFailure.of(plan.requests[0], "broken.mcap: not an MCAP file")
    report = reduce_run(plan, [], [failure])
    assert report.episodes == 1
    record = json.loads((out / "meta/provenance/run-001.json").read_text())
    assert [Path(e["bag_uri"]).name for e in record["excluded"]] == ["broken.mcap"]
    assert plan_run(config).requests == ()  # unchanged: not retried
    assert validate_dataset(out, repo_id="test/alone", decode_every=10).episodes == 1


def test_an_incompatible_append_is_refused_before_anything_converts(tmp_path: Path) -> None:
    """Finding 6 of issue 16: the append was refused only after every bag had been converted."""
    bags = tmp_path / "bags"
    write_episode_bag(bags / "first", "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS))
    out = tmp_path / "ds"
    config = ConvertConfig(
        bags_glob=str(bags / "*"),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        encoder=FAST_CODEC,
        append=True,
    )
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    write_episode_bag(bags / "second", "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS))
    text = SAMPLE_CONTRACT.read_text()
    start = text.index("  - key: observation.images.wrist")
    no_wrist = tmp_path / "no_wrist.yaml"
    no_wrist.write_text(text[:start] + text[text.index("actions:") :])
    with pytest.raises(
        DatasetWriteError, match=r"only in the dataset: observation\.images\.wrist.*nothing was"
    ):
        plan_run(config.model_copy(update={"contract": str(no_wrist)}))
    # the same features for another robot: info.json holds one robot type, which would relabel the dataset
    other_robot = tmp_path / "other_robot.yaml"
    other_robot.write_text(text.replace("robot_type: bagport_sample_arm", "robot_type: other_arm", 1))
    with pytest.raises(
        DatasetWriteError,
        match=r"robot_type: dataset 'bagport_sample_arm', contract 'other_arm'.*nothing was",
    ):
        plan_run(config.model_copy(update={"contract": str(other_robot)}))


def test_a_plan_is_up_to_date_only_when_the_dataset_is_what_it_would_write(tmp_path: Path) -> None:
    bags = tmp_path / "bags"
    for i in range(2):
        write_episode_bag(
            bags / f"bag{i}", "mcap", EpisodeSpec(duration_s=0.5, seed=i, cameras=SMALL_CAMERAS)
        )
    out = tmp_path / "ds"
    config = ConvertConfig(
        bags_glob=str(bags / "*"), contract=str(SAMPLE_CONTRACT), output=str(out),
        staging=str(tmp_path / "staging"), encoder=FAST_CODEC, keep_staging=True,
    )  # fmt: skip
    plan = plan_run(config)
    assert not plan.up_to_date
    reduce_run(plan, stage_all(plan))
    again = config.model_copy(update={"overwrite": True})
    plan = plan_run(again)
    assert (plan.up_to_date, plan.requests, len(plan.reused)) == (True, (), 2)
    # options that change the output, or another format, or an append: not up to date
    assert not plan_run(again.model_copy(update={"data_files_size_in_mb": 1.0})).up_to_date
    assert not plan_run(again.model_copy(update={"repo_id": "someone/else"})).up_to_date
    # a file LeRobot would read that the run did not write, or one it wrote missing: written again
    stray = out / "data/chunk-000/extra.parquet"  # (repair removes a stray file-NNN after the last one)
    stray.write_bytes(b"")
    assert not plan_run(again).up_to_date
    stray.unlink()
    assert plan_run(again).up_to_date
    (out / "meta/stats.json").rename(tmp_path / "stats.json")
    assert not plan_run(again).up_to_date
    (tmp_path / "stats.json").rename(out / "meta/stats.json")
    # without --overwrite an existing output is refused as before
    with pytest.raises(DatasetWriteError, match="already exists"):
        plan_run(config)
    # the up-to-date run without --keep-staging removes the staged episodes, as a write would
    report = finish_up_to_date(plan_run(again.model_copy(update={"keep_staging": False})))
    assert (report.converted, len(report.reused), report.episodes) == (0, 2, 2)
    assert not (tmp_path / "staging").exists()
    # with its staging gone, an unchanged fleet is still up to date (each bag judged by its stamp now)...
    plan = plan_run(again)
    assert (plan.up_to_date, plan.requests, len(plan.reused)) == (True, (), 2)
    assert (finish_up_to_date(plan).converted, len(plan_run(again).reused)) == (0, 2)
    # ...and a bag whose file changed is not: every bag converts again (none is staged to reuse)
    recording = next((bags / "bag1").glob("*.mcap"))
    recording.write_bytes(recording.read_bytes())  # the same bytes, a new modification time
    plan = plan_run(again)
    assert (plan.up_to_date, len(plan.requests), plan.reused) == (False, 2, ())
    assert validate_dataset(out, repo_id="test/up-to-date", decode_every=10).episodes == 2


def test_an_object_store_dataset_is_up_to_date_by_one_listing(tmp_path: Path, s3_env: dict[str, str]) -> None:
    """The same check on S3 (moto's real HTTP endpoint through s3fs): the run record's key, and every
    object the run wrote there with nothing else under ``data/``."""
    fs = S3FileSystem()
    fs.mkdir("uptodate")
    bags = tmp_path / "bags"
    write_episode_bag(bags / "bag0", "mcap", EpisodeSpec(duration_s=0.5, cameras=SMALL_CAMERAS))
    config = ConvertConfig(
        bags_glob=str(bags / "*"), contract=str(SAMPLE_CONTRACT), output="s3://uptodate/ds",
        staging=str(tmp_path / "staging"), encoder=FAST_CODEC, keep_staging=True,
    )  # fmt: skip
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    again = config.model_copy(update={"overwrite": True})
    assert plan_run(again).up_to_date
    fs.pipe("uptodate/ds/data/chunk-000/extra.parquet", b"")
    fs.invalidate_cache()
    assert not plan_run(again).up_to_date


def test_overwrite_never_removes_a_folder_that_is_not_a_dataset(fleet: Path, tmp_path: Path) -> None:
    """A typo in --output, or the bags' own folder as --output: refused before anything runs, kept whole."""
    config = ConvertConfig(
        manifest=str(fleet / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(fleet),
        staging=str(tmp_path / "staging"), encoder=FAST_CODEC, overwrite=True,
    )  # fmt: skip
    before = sorted(p.relative_to(fleet).as_posix() for p in fleet.rglob("*"))
    with pytest.raises(DatasetWriteError, match="is not a dataset"):
        plan_run(config)
    assert sorted(p.relative_to(fleet).as_posix() for p in fleet.rglob("*")) == before


@pytest.mark.parametrize("append", [False, True], ids=["new", "append"])
def test_an_output_inside_a_bag_folder_is_refused_before_anything_is_written(
    fleet: Path, tmp_path: Path, append: bool
) -> None:
    """``--output bags/ep1/out`` used to write the dataset into the recording."""
    config = ConvertConfig(
        manifest=str(fleet / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(fleet / "c/out"),
        staging=str(tmp_path / "staging"), encoder=FAST_CODEC, append=append,
    )  # fmt: skip
    before = sorted(p.relative_to(fleet).as_posix() for p in fleet.rglob("*"))
    with pytest.raises(
        DatasetWriteError, match=r"--output .*/c/out is inside the bag .*/c: the dataset would"
    ):
        plan_run(config)
    assert sorted(p.relative_to(fleet).as_posix() for p in fleet.rglob("*")) == before
    # a --staging inside the bag: the staged episodes would go into the recording
    staged_in_bag = config.model_copy(
        update={"output": str(tmp_path / "out"), "staging": str(fleet / "c/st")}
    )
    with pytest.raises(
        DatasetWriteError, match=r"--staging .*/c/st is inside the bag .*/c: the staged episodes"
    ):
        plan_run(staged_in_bag)
    assert sorted(p.relative_to(fleet).as_posix() for p in fleet.rglob("*")) == before


def _convert_all(
    plan: RunPlan, *, retryable: bool = False
) -> tuple[list[PlannedEpisode], list[EpisodeFailure]]:
    """What the flow does with each bag: staged, or its failure (``retryable``: as a transient error's)."""
    staged: list[PlannedEpisode] = list(plan.reused)
    failures: list[EpisodeFailure] = []
    for request in plan.requests:
        try:
            convert_episode(request)
        except BagportError as err:
            failures.append(EpisodeFailure.of(request, str(err), retryable=retryable))
        else:
            staged.append(PlannedEpisode.of(request))
    return staged, failures


def test_an_unchanged_fleet_with_a_broken_bag_is_up_to_date_and_a_transient_failure_is_retried(
    fleet: Path, tmp_path: Path
) -> None:
    """A fleet nearly always holds a bag that cannot be converted: that bag, unchanged, fails the same way,
    so a re-run with --overwrite is still up to date (the bag listed as not tried again); changed, or failed
    for a transient reason (not the bag's fault), it is tried again, and an append retries only the latter."""
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a bag at all")
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text(f"bags:\n  - uri: {fleet / 'a'}\n  - uri: {broken}\n")
    config = ConvertConfig(
        manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output=str(tmp_path / "ds"),
        staging=str(tmp_path / "staging"), encoder=FAST_CODEC, overwrite=True,
    )  # fmt: skip
    plan = plan_run(config)
    report = reduce_run(plan, *_convert_all(plan))
    assert (report.episodes, len(report.excluded), report.converted) == (1, 1, 1)  # the broken bag: excluded
    again = plan_run(config)
    assert (again.up_to_date, again.requests, len(again.reused)) == (True, (), 1)
    assert [f.bag_uri for f in again.settled_failures] == [str(broken)]
    assert [row.bag_uri for row in finish_up_to_date(again).excluded] == [str(broken)]
    # the broken bag given another window (another request): not up to date, it is tried again
    windowed = tmp_path / "windowed.yaml"
    windowed.write_text(f"bags:\n  - uri: {fleet / 'a'}\n  - uri: {broken}\n    start_s: 0.5\n")
    assert str(broken) in [
        r.bag_uri for r in plan_run(config.model_copy(update={"manifest": str(windowed)})).requests
    ]
    # the broken bag rewritten (another stamp): not up to date, it is tried again
    broken.write_bytes(b"still not a bag, but other bytes")
    assert str(broken) in [r.bag_uri for r in plan_run(config).requests]
    # a run whose broken bag failed for a transient reason: never up to date, and an append retries it
    plan = plan_run(config)
    reduce_run(plan, *_convert_all(plan, retryable=True))
    again = plan_run(config)
    assert not again.up_to_date and str(broken) in [r.bag_uri for r in again.requests]
    appending = plan_run(config.model_copy(update={"overwrite": False, "append": True}))
    assert [r.bag_uri for r in appending.requests] == [str(broken)]


def test_codec_settings_the_encoder_refuses_stop_the_plan_before_any_episode(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "bags" / "a", "mcap", EpisodeSpec(duration_s=0.3, cameras=SMALL_CAMERAS))
    config = ConvertConfig(
        bags_glob=str(tmp_path / "bags" / "*"), contract=str(SAMPLE_CONTRACT), output=str(tmp_path / "out"),
        encoder={"codec": "libsvtav1", "crf": 99},
    )  # fmt: skip
    with pytest.raises(EncoderSettingsError, match="crf=99") as err:
        plan_run(config)
    assert err.value.codec == "libsvtav1"
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.staging").exists()
