"""Re-runs cost only their new work: the plan lists the staging store once and submits conversion tasks
only for episodes not staged with a matching key; what the current manifest decides (entry, order,
metadata) is applied when the dataset is written, never taken from a staged episode's record."""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import av
import pandas as pd
import pyarrow.parquet as pq
import pytest
import yaml
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import (
    ArtifactFilter,
    ArtifactFilterFlowRunId,
    FlowRunFilter,
    FlowRunFilterId,
)
from prefect.client.schemas.sorting import FlowRunSort
from prefect.task_runners import ThreadPoolTaskRunner

import flows.convert
from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.cli import main
from flows.convert import run_config
from flows.runners import prefect_api
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

pytestmark = pytest.mark.slow

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)
SUBMITTED: list[str] = []
"""Labels of the episodes submitted to the task runner in conversion tasks, in order."""
BATCHES: list[int] = []
"""Sizes of the batch task runs submitted."""


class _CountingRunner(ThreadPoolTaskRunner[Any]):
    """Prefect's thread-pool runner, recording every conversion task submitted to it."""

    def submit(self, task: Any, parameters: dict[str, Any], *args: Any, **kwargs: Any) -> Any:
        if task.name == "convert-episode":
            SUBMITTED.append(str(parameters["label"]))
        elif task.name == "convert-episodes":  # a batch of small episodes
            SUBMITTED.extend(str(label) for label in parameters["labels"])
            BATCHES.append(len(parameters["labels"]))
        return super().submit(task, parameters, *args, **kwargs)


@pytest.fixture(scope="module")
def prefect() -> Iterator[None]:
    with prefect_api(), pytest.MonkeyPatch.context() as patch:
        patch.setattr(flows.convert, "ThreadPoolTaskRunner", _CountingRunner)
        yield


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bags")
    for i in (4, 5, 7):
        spec = EpisodeSpec(duration_s=0.6, seed=i, cameras=CAMERAS, task=f"task of bag {i:03d}")
        write_episode_bag(root / f"bag_{i:03d}", "mcap", spec)
    return root


def _manifest(bags: Path, name: str, entries: list[tuple[int, str]]) -> Path:
    path = bags / f"{name}.yaml"
    body = [{"uri": f"bag_{i:03d}", "metadata": {"operator": who}} for i, who in entries]
    path.write_text(yaml.safe_dump({"bags": body}))
    return path


def _convert(manifest: Path, out: Path, staging: Path, **options: Any) -> tuple[DatasetReport, list[str]]:
    config = ConvertConfig(
        manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output=str(out), staging=str(staging),
        encoder=FAST_CODEC, runner="thread", workers=1, keep_staging=True, **options,
    )  # fmt: skip
    SUBMITTED.clear()
    BATCHES.clear()
    report = run_config(config)
    return report, list(SUBMITTED)


def _rows(files: list[Path]) -> list[dict[str, Any]]:
    return [row for f in files for row in pq.read_table(f).to_pylist()]


def _dataset(root: Path) -> dict[str, Any]:
    """What must be identical between two writes of the same episodes: data rows, meta, video frames."""
    frames = {}
    for video in sorted(root.glob("videos/**/*.mp4")):
        with av.open(str(video)) as container:
            frames[video.relative_to(root).as_posix()] = sum(1 for _ in container.decode(video=0))
    return {
        "data": _rows(sorted(root.glob("data/*/*.parquet"))),
        "episodes": _rows(sorted(root.glob("meta/episodes/*/*.parquet"))),
        "info": json.loads((root / "meta/info.json").read_text()),
        "stats": json.loads((root / "meta/stats.json").read_text()),
        "tasks": _rows([root / "meta/tasks.parquet"]),
        "video_frames": frames,
    }


def _record(root: Path) -> dict[str, Any]:
    record: dict[str, Any] = json.loads((root / "meta/provenance/run.json").read_text())
    return record


def test_a_rerun_converts_only_what_is_not_staged(prefect: None, bags: Path, tmp_path: Path) -> None:
    manifest = _manifest(bags, "three", [(4, "alice"), (5, "alice"), (7, "alice")])
    staging = tmp_path / "staging"
    first, submitted = _convert(manifest, tmp_path / "first", staging)
    assert sorted(submitted) == ["bag_004", "bag_005", "bag_007"]
    assert (first.converted, first.reused) == (3, ())

    # everything staged: no conversion task at all, and the same dataset
    again, submitted = _convert(manifest, tmp_path / "again", staging)
    assert submitted == []
    assert again.converted == 0
    assert [Path(uri).name for uri in again.reused] == ["bag_004", "bag_005", "bag_007"]
    assert _dataset(tmp_path / "again") == _dataset(tmp_path / "first")
    record = _record(tmp_path / "again")
    assert record["episodes_reused"] == 3
    assert record["manifest"]["reused"] == [str(bags / f"bag_{i:03d}") for i in (4, 5, 7)]

    # a bag whose files changed converts again, and only that one
    touched = next((bags / "bag_005").glob("*.mcap"))
    stat = touched.stat()
    os.utime(touched, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    third, submitted = _convert(manifest, tmp_path / "third", staging)
    assert submitted == ["bag_005"]
    assert (third.converted, len(third.reused)) == (1, 2)
    assert _dataset(tmp_path / "third")["data"] == _dataset(tmp_path / "first")["data"]


def test_overlapping_windows_of_a_bag_are_converted_with_a_warning_on_the_cli(
    prefect: None, bags: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = bags / "overlap.yaml"
    windows = [
        {"uri": "bag_004", "start_s": 0.0, "end_s": 0.4},
        {"uri": "bag_004", "start_s": 0.3, "end_s": 0.6},
    ]
    manifest.write_text(yaml.safe_dump({"bags": windows}))
    argv = ["convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT)]
    assert (
        main([*argv, "--output", str(tmp_path / "ds"), "--runner", "thread", "--workers", "1", "--quiet"])
        == 0
    )
    warned = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning: ")]
    assert warned == [
        f"warning: bags[1] {bags / 'bag_004'}: its window 0.3..0.6 s overlaps bags[0]'s window 0..0.4 s: the "
        "frames in both are in two episodes (give each entry its own part of the bag if that is not meant)"
    ]
    assert json.loads((tmp_path / "ds/meta/info.json").read_text())["total_episodes"] == 2


def test_append_of_bags_all_in_the_dataset_submits_nothing_and_exits_0(
    prefect: None, bags: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = _manifest(bags, "two", [(4, "alice"), (7, "alice")])
    out = tmp_path / "ds"
    _convert(manifest, out, tmp_path / "staging", append=True)
    before = _dataset(out)
    SUBMITTED.clear()
    started = time.perf_counter()
    code = main([
        "convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out),
        "--append", "--runner", "thread", "--workers", "1", "--quiet",
    ])  # fmt: skip
    elapsed_s = time.perf_counter() - started
    assert code == 0
    assert SUBMITTED == []
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"nothing to do: every bag is in {out} already, or was left out")
    assert "(2 episode(s)" in lines[0]
    assert _dataset(out) == before
    assert elapsed_s < 60  # a generous bound against a hang, not a benchmark (see BENCHMARKS.md W4)
    # its JSON summary says where the dataset is, as any run's does
    argv = ["convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out)]
    assert main([*argv, "--append", "--runner", "thread", "--workers", "1"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["outputs"], summary["converted_now"], summary["episodes"]) == (
        {"lerobot": str(out)},
        0,
        2,
    )


def test_reused_episodes_take_the_current_manifests_entry_order_and_metadata(
    prefect: None, bags: Path, tmp_path: Path
) -> None:
    """Issue 19's finding 3: manifest a = [004, 005] with --keep-staging, then b = [007, 004, 005] on
    the same staging store gave the order 004, 007, 005, and two bags claimed bags[0]."""
    staging = tmp_path / "staging"
    _convert(_manifest(bags, "a", [(4, "alice"), (5, "alice")]), tmp_path / "a", staging)
    report, submitted = _convert(
        _manifest(bags, "b", [(7, "bob"), (4, "bob"), (5, "carol")]), tmp_path / "b", staging
    )
    assert submitted == ["bag_007"]
    assert [Path(uri).name for uri in report.reused] == ["bag_004", "bag_005"]
    episodes = _record(tmp_path / "b")["episodes"]
    assert [(e["episode_index"], Path(e["bag_uri"]).name, e["manifest_entry"]) for e in episodes] == [
        (0, "bag_007", 0),
        (1, "bag_004", 1),
        (2, "bag_005", 2),
    ]
    assert [e["metadata"] for e in episodes] == [
        {"operator": "bob"},
        {"operator": "bob"},
        {"operator": "carol"},
    ]
    meta = pd.concat([pd.read_parquet(p) for p in sorted((tmp_path / "b").glob("meta/episodes/*/*.parquet"))])
    assert [list(t) for t in meta["tasks"]] == [["task of bag 007"], ["task of bag 004"], ["task of bag 005"]]
    assert [e.manifest_entry for e in report.qa] == [0, 1, 2]
    # the rows of episode 1 are bag 004's, as episode 0 of the first dataset
    data_a = pd.read_parquet(next((tmp_path / "a").glob("data/*/*.parquet")))
    data_b = pd.concat([pd.read_parquet(p) for p in sorted((tmp_path / "b").glob("data/*/*.parquet"))])
    state_a = data_a[data_a["episode_index"] == 0]["observation.state"].tolist()
    state_b = data_b[data_b["episode_index"] == 1]["observation.state"].tolist()
    assert [list(v) for v in state_b] == [list(v) for v in state_a]


def test_small_episodes_share_a_task_run_and_each_bag_fails_alone(
    prefect: None, bags: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(flows.convert, "batch_size", lambda episodes, workers: 2)
    (bags / "broken.mcap").write_bytes(b"this is not an MCAP file")
    manifest = bags / "with-broken.yaml"
    manifest.write_text(
        "bags:\n" + "".join(f"  - uri: {n}\n" for n in ("bag_004", "broken.mcap", "bag_005", "bag_007"))
    )
    report, submitted = _convert(manifest, tmp_path / "ds", tmp_path / "staging")
    assert BATCHES == [2, 2]
    assert submitted == ["bag_004", "broken.mcap", "bag_005", "bag_007"]
    assert report.episodes == 3
    assert [(row.manifest_entry, Path(row.bag_uri).name) for row in report.excluded] == [(1, "broken.mcap")]
    assert "broken.mcap" in report.excluded[0].reason
    assert "conversion failed" in report.excluded[0].reason
    episodes = _record(tmp_path / "ds")["episodes"]
    assert [Path(e["bag_uri"]).name for e in episodes] == ["bag_004", "bag_005", "bag_007"]


def _files(root: Path) -> dict[str, tuple[bytes, int]]:
    """Every file of the dataset: its bytes and modification time."""
    return {
        p.relative_to(root).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


async def _latest_run() -> tuple[list[str], dict[str, Any]]:
    """The newest flow run's task run names and artifacts (through the Prefect API)."""
    async with get_client() as client:
        run = (await client.read_flow_runs(sort=FlowRunSort.START_TIME_DESC, limit=1))[0]
        tasks = await client.read_task_runs(flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[run.id])))
        artifacts = await client.read_artifacts(
            artifact_filter=ArtifactFilter(flow_run_id=ArtifactFilterFlowRunId(any_=[run.id]))
        )
        return sorted(t.name for t in tasks), {str(a.key): a.data for a in artifacts if a.key}


def test_an_up_to_date_rerun_writes_nothing_and_a_change_writes_again(
    prefect: None, bags: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = _manifest(bags, "uptodate", [(4, "alice"), (5, "alice"), (7, "alice")])
    out, staging = tmp_path / "ds", tmp_path / "staging"
    _convert(manifest, out, staging)
    first = _files(out)
    codec = tmp_path / "codec.yaml"
    codec.write_text(yaml.safe_dump(FAST_CODEC))
    argv = [
        "convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out),
        "--staging", str(staging), "--keep-staging", "--overwrite", "--runner", "thread", "--workers", "1",
        "--codec", str(codec),
    ]  # fmt: skip
    capsys.readouterr()
    SUBMITTED.clear()
    assert main(argv) == 0
    # no task run at all (no plan task either: the CLI planned before Prefect started), nothing written
    assert SUBMITTED == []
    task_runs, artifacts = asyncio.run(_latest_run())
    assert task_runs == []
    assert _files(out) == first
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert (summary["up_to_date"], summary["reused"], summary["converted_now"]) == (True, 3, 0)
    assert f"up to date: 3 episode(s) reused, nothing to write at {out}" in captured.err
    assert "**up to date**: 3 episode(s) reused" in artifacts["bagport-summary"]

    # another option that changes the output (file size limits): written again, from the staging store
    report, submitted = _convert(manifest, out, staging, overwrite=True, chunks_size=2)
    assert (submitted, report.converted, len(report.reused)) == ([], 0, 3)
    assert _files(out) != first

    # the same options again: up to date
    written = _files(out)
    report, submitted = _convert(manifest, out, staging, overwrite=True, chunks_size=2)
    assert (submitted, len(report.reused), report.qa) == ([], 3, ())
    assert _files(out) == written

    # a bag whose files changed: that one converts, and the dataset is written
    touched = next((bags / "bag_007").glob("*.mcap"))
    stat = touched.stat()
    os.utime(touched, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    report, submitted = _convert(manifest, out, staging, overwrite=True, chunks_size=2)
    assert (submitted, report.converted) == (["bag_007"], 1)
    assert _files(out) != written

    # another contract (the same features, one comment more): every episode converts again
    contract = tmp_path / "contract.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text() + "\n# revised\n")
    written = _files(out)
    config = ConvertConfig(
        manifest=str(manifest), contract=str(contract), output=str(out), staging=str(staging),
        encoder=FAST_CODEC, runner="thread", workers=1, keep_staging=True, overwrite=True, chunks_size=2,
    )  # fmt: skip
    SUBMITTED.clear()
    report = run_config(config)
    assert sorted(SUBMITTED) == ["bag_004", "bag_005", "bag_007"]
    assert report.converted == 3
    assert _files(out) != written


def test_without_a_prefect_api_an_up_to_date_run_starts_no_flow(
    prefect: None,
    bags: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With bagport's temporary server (no PREFECT_API_URL), whose records end with the run, an up-to-date
    run and an append with nothing new finish before Prefect: no flow run, the server stopped unused."""
    manifest = _manifest(bags, "throwaway", [(4, "alice"), (5, "alice")])
    out, staging = tmp_path / "ds", tmp_path / "staging"
    _convert(manifest, out, staging)
    first = _files(out)
    flows_run: list[str] = []
    run_convert = flows.convert.run_convert

    def spy(*args: Any, **kwargs: Any) -> DatasetReport:
        flows_run.append("flow")
        return run_convert(*args, **kwargs)

    monkeypatch.setattr(flows.convert, "run_convert", spy)
    monkeypatch.delenv("PREFECT_API_URL")
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "prefect-home"))  # no profile with an API either
    monkeypatch.chdir(tmp_path)
    codec = tmp_path / "codec.yaml"
    codec.write_text(yaml.safe_dump(FAST_CODEC))
    argv = [
        "convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out),
        "--staging", str(staging), "--keep-staging", "--runner", "thread", "--workers", "1",
        "--codec", str(codec), "--quiet",
    ]  # fmt: skip
    capsys.readouterr()
    assert main([*argv, "--overwrite"]) == 0
    assert main([*argv, "--append"]) == 0
    assert flows_run == []
    assert _files(out) == first
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith(f"up to date: 2 episode(s) reused, nothing to write at {out}")
    assert lines[1].startswith(f"nothing to do: every bag is in {out} already, or was left out")
    assert "(2 episode(s)" in lines[1]


def test_a_cli_run_recovers_the_output_once(
    prefect: None, bags: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Publish recovery (the journal's repair) runs once per run: when the run is planned, not again
    when the dataset is written (``flows/reduce.py`` opens the write with ``repaired=True``)."""
    import bagport.dataset.repair  # noqa: PLC0415
    import bagport.dataset.session  # noqa: PLC0415
    import bagport.run  # noqa: PLC0415

    calls: list[str] = []
    real = bagport.dataset.repair.repair_dataset

    def counting(output: str, **options: Any) -> Any:
        calls.append(output)
        return real(output, **options)

    monkeypatch.setattr(bagport.run, "repair_dataset", counting)
    monkeypatch.setattr(bagport.dataset.session, "repair_dataset", counting)
    manifest = _manifest(bags, "once", [(4, "alice")])
    out = tmp_path / "ds"
    code = main([
        "convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out),
        "--staging", str(tmp_path / "staging"), "--runner", "thread", "--workers", "1", "--quiet",
    ])  # fmt: skip
    assert code == 0
    assert calls == [str(out)]
    assert (out / "meta" / "info.json").is_file()


def test_batches_keep_every_worker_busy_to_the_end_and_stay_bounded() -> None:
    batch_size = flows.convert.batch_size
    assert batch_size(15, 2) == 1  # fewer than 8 bags per worker: each bag its own task run
    assert batch_size(16, 2) == 2
    assert batch_size(200, 2) == 25  # W3: 8 task runs, 4 per worker
    assert batch_size(2000, 2) == flows.convert.MAX_BATCH == 32  # W4: 63 task runs
    for episodes in range(1, 3000, 7):
        for workers in (1, 2, 8):
            size = batch_size(episodes, workers)
            task_runs = -(-episodes // size)
            assert 1 <= size <= flows.convert.MAX_BATCH
            assert task_runs >= min(episodes, flows.convert.TASK_RUNS_PER_WORKER * workers)


def test_an_unchanged_broken_bag_does_not_stop_a_rerun_from_being_up_to_date(
    prefect: None, bags: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A fleet with a bag that cannot be converted: the re-run is up to date, says the bag was not tried
    again, and exits 0 (the first run reported it, exit 1); nothing is submitted or written."""
    (bags / "broken.mcap").write_bytes(b"not a bag")
    manifest = bags / "with_broken.yaml"
    manifest.write_text(yaml.safe_dump({"bags": [{"uri": "bag_004"}, {"uri": "broken.mcap"}]}))
    out = tmp_path / "ds"
    report, _ = _convert(manifest, out, tmp_path / "staging")
    assert (report.episodes, len(report.excluded), report.converted) == (1, 1, 1)
    first = _files(out)
    codec = tmp_path / "codec.yaml"
    codec.write_text(yaml.safe_dump(FAST_CODEC))
    capsys.readouterr()
    SUBMITTED.clear()
    argv = [
        "convert", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--output", str(out),
        "--staging", str(tmp_path / "staging"), "--overwrite", "--runner", "thread", "--workers", "1",
        "--codec", str(codec),
    ]  # fmt: skip
    assert main(argv) == 0
    assert SUBMITTED == [] and _files(out) == first
    err = capsys.readouterr().err
    assert "up to date: 1 episode(s) reused, 1 bag(s) that failed to convert before and are unchanged" in err
