"""The reduce as a map on a real Dask cluster of two worker processes: every output file, each data file
and each video file, is written by its own task on a worker (the task stream shows them), into the local
build folder beside the output; the commit publishes, ``bagport validate`` passes and LeRobot loads every
frame with the values the synthetic bags hold. An append on the cluster adds files without reading the
old ones. On the local process pool, the file tasks run on threads of the flow's process: a run with every
episode staged starts no pool worker."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from distributed import get_task_stream
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterId
from prefect.client.schemas.sorting import FlowRunSort
from prefect.task_runners import ProcessPoolTaskRunner

from bagport.config import ConvertConfig
from bagport.dataset.validate import video_backend
from bagport.synth import EpisodeSpec, GroundTruth, write_episode_bag
from flows.convert import run_config
from flows.runners import prefect_api
from tests.dask_cluster import dask_cluster
from tests.fsprobe import watch_opens
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT


def _convert(tmp_path: Path, names: list[str], *extra: str) -> subprocess.CompletedProcess[str]:
    manifest = tmp_path / f"manifest-{len(names)}.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {tmp_path / n}\n" for n in names))
    return subprocess.run(
        [
            sys.executable, "-m", "flows.cli", "convert", "--manifest", str(manifest),
            "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "ds"),
            "--staging", str(tmp_path / "staging"), "--video-files-size-in-mb", "0.001",
            "--data-files-size-in-mb", "0.001", *extra,
        ],
        capture_output=True, text=True, check=False, cwd=REPO, env={**os.environ, "BAGPORT_DEBUG": "0"},
    )  # fmt: skip


def _check_values(root: Path, episodes: int) -> None:
    """Every frame LeRobot loads holds its bag's true joint positions at the stamp the provenance says
    was held, at the global index the episodes' metadata gives it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    rows = pq.read_table(sorted((root / "meta/provenance").glob("chunk-*/file-*.parquet"))).to_pylist()
    state = {
        (r["episode_index"], r["frame_index"]): (r["index"], r["source_header_ns"])
        for r in rows
        if r["key"] == "observation.state"
    }
    dataset = LeRobotDataset("test/map", root=root, video_backend=video_backend())
    truths = [GroundTruth(EpisodeSpec(duration_s=0.5, seed=n)) for n in range(episodes)]
    for index in range(len(dataset)):
        item = dataset[index]
        episode, frame = int(item["episode_index"]), int(item["frame_index"])
        provenance_index, held_ns = state[episode, frame]
        assert int(item["index"]) == index == provenance_index
        np.testing.assert_allclose(
            item["observation.state"].numpy(), truths[episode].joint_position(held_ns), atol=1e-6
        )
    assert len(dataset) == len(state) == 15 * episodes


@pytest.mark.slow
def test_output_files_are_written_by_tasks_on_two_dask_workers(tmp_path: Path) -> None:
    for n in range(4):
        write_episode_bag(tmp_path / f"ep{n}", "mcap", EpisodeSpec(duration_s=0.5, seed=n))
    first = _convert(tmp_path, ["ep0", "ep1"], "--runner", "thread")
    assert first.returncode == 0, first.stderr[-3000:]
    old = sorted(p for d in ("data", "videos") for p in (tmp_path / "ds" / d).rglob("*") if p.is_file())
    assert len(old) == 6  # per episode: a data file (above 1 kB each) and a video file per camera
    # one CLI run per cluster: its workers keep the first run's (temporary) Prefect API
    with dask_cluster() as (scheduler_address, client):
        workers = client.run(os.getpid)
        with get_task_stream(client) as stream, watch_opens(old) as opens:
            appended = _convert(
                tmp_path, ["ep0", "ep1", "ep2", "ep3"], "--append", "--runner", "dask", "--dask-address",
                scheduler_address,
            )  # fmt: skip
    assert appended.returncode == 0, appended.stderr[-3000:]
    # the two new data files and each camera's two new video files: one task each, on the workers
    wrote = [t for t in stream.data if str(t["key"]).startswith("write_file_task-")]
    assert len(wrote) == 6
    assert {t["worker"] for t in wrote} <= set(workers) and os.getpid() not in workers.values()
    data = sorted(
        p.relative_to(tmp_path / "ds").as_posix() for p in (tmp_path / "ds/data").rglob("*.parquet")
    )
    assert data == [f"data/chunk-000/file-{n:03d}.parquet" for n in range(4)]
    assert opens.events == []  # the append opened none of the existing data or video files
    check = subprocess.run(
        [sys.executable, "-m", "flows.cli", "validate", str(tmp_path / "ds")],
        capture_output=True, text=True, check=False, cwd=REPO,
    )  # fmt: skip
    assert check.returncode == 0, check.stdout + check.stderr
    assert "4 episode(s), 60 frames, 60 decoded through LeRobot" in check.stdout, check.stdout
    _check_values(tmp_path / "ds", 4)


POOL_TASKS: list[str] = []
"""Names of the tasks submitted to the process pool."""


_POOL_SUBMIT = ProcessPoolTaskRunner.submit


def _counting_submit(
    self: ProcessPoolTaskRunner, task: Any, parameters: dict[str, Any], *args: Any, **kwargs: Any
) -> Any:
    """Prefect's process-pool submit, recording the task (the runner itself is pickled to its workers,
    so it stays Prefect's class)."""
    POOL_TASKS.append(str(task.name))
    return _POOL_SUBMIT(self, task, parameters, *args, **kwargs)


async def _latest_task_runs() -> list[str]:
    async with get_client() as client:
        run = (await client.read_flow_runs(sort=FlowRunSort.START_TIME_DESC, limit=1))[0]
        tasks = await client.read_task_runs(flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[run.id])))
        return sorted(t.name for t in tasks)


@pytest.mark.slow
def test_on_the_process_pool_files_are_written_by_threads_and_a_staged_run_starts_no_worker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for n in range(2):
        write_episode_bag(tmp_path / f"ep{n}", "mcap", EpisodeSpec(duration_s=0.5, seed=n))
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {tmp_path / f'ep{n}'}\n" for n in range(2)))
    monkeypatch.setattr(ProcessPoolTaskRunner, "submit", _counting_submit)

    def convert(out: str) -> list[str]:
        POOL_TASKS.clear()
        config = ConvertConfig(
            manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output=str(tmp_path / out),
            staging=str(tmp_path / "staging"), encoder=FAST_CODEC, runner="process", workers=2,
            keep_staging=True,
        )  # fmt: skip
        report = run_config(config)
        assert report.episodes == 2
        return list(POOL_TASKS)

    with prefect_api():
        first = convert("first")
        assert first and "write-file" not in first  # the episodes convert on the pool, the files are not
        assert convert("again") == []  # every episode staged: nothing on the pool, no worker started
        written = [name for name in asyncio.run(_latest_task_runs()) if name.startswith("write ")]
    again = tmp_path / "again"
    files = sorted(
        p.relative_to(again).as_posix()
        for d in ("data", "videos")
        for p in (again / d).rglob("*")
        if p.is_file()
    )
    assert len(written) == len(files) == 1 + 2  # one data file, one video file per camera: a task run each
    for rel in files:
        assert (tmp_path / "again" / rel).read_bytes() == (tmp_path / "first" / rel).read_bytes()
