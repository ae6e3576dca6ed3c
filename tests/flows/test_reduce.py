"""The reduce as a map on a real Dask cluster of two worker processes: every output file is written by its
own task on a worker (the task stream shows them), into the local build folder beside the output; the
commit publishes, ``bagport validate`` passes and LeRobot loads every frame. An append on the cluster
adds files without reading the old ones."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from distributed import Client, LocalCluster, get_task_stream

from bagport.synth import EpisodeSpec, write_episode_bag
from tests.fsprobe import watch_opens
from tests.helpers import REPO, SAMPLE_CONTRACT


def _convert(tmp_path: Path, names: list[str], *extra: str) -> subprocess.CompletedProcess[str]:
    manifest = tmp_path / f"manifest-{len(names)}.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {tmp_path / n}\n" for n in names))
    return subprocess.run(
        [
            sys.executable, "-m", "flows.cli", "convert", "--manifest", str(manifest),
            "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "ds"),
            "--staging", str(tmp_path / "staging"), "--video-files-size-in-mb", "0.001", *extra,
        ],
        capture_output=True, text=True, check=False, cwd=REPO, env={**os.environ, "BAGPORT_DEBUG": "0"},
    )  # fmt: skip


@pytest.mark.slow
def test_output_files_are_written_by_tasks_on_two_dask_workers(tmp_path: Path) -> None:
    for n in range(3):
        write_episode_bag(tmp_path / f"ep{n}", "mcap", EpisodeSpec(duration_s=0.5, seed=n))
    first = _convert(tmp_path, ["ep0", "ep1"], "--runner", "thread")
    assert first.returncode == 0, first.stderr[-3000:]
    old = sorted(p for d in ("data", "videos") for p in (tmp_path / "ds" / d).rglob("*") if p.is_file())
    assert len(old) == 5  # one data file, one video file per episode and camera (clips above 1 kB)
    # one CLI run per cluster: its workers keep the first run's (temporary) Prefect API
    with (
        LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        Client(cluster) as client,  # type: ignore[no-untyped-call]
    ):
        workers = client.run(os.getpid)
        with get_task_stream(client) as stream, watch_opens(old) as opens:
            appended = _convert(
                tmp_path, ["ep0", "ep1", "ep2"], "--append", "--runner", "dask", "--dask-address",
                cluster.scheduler_address,
            )  # fmt: skip
    assert appended.returncode == 0, appended.stderr[-3000:]
    # the new data file and each camera's new video file: one task each, on the workers
    wrote = [t for t in stream.data if str(t["key"]).startswith("write_file_task-")]
    assert len(wrote) == 3
    assert {t["worker"] for t in wrote} <= set(workers) and os.getpid() not in workers.values()
    assert opens.events == []  # the append opened none of the existing data or video files
    check = subprocess.run(
        [sys.executable, "-m", "flows.cli", "validate", str(tmp_path / "ds")],
        capture_output=True, text=True, check=False, cwd=REPO,
    )  # fmt: skip
    assert check.returncode == 0, check.stdout + check.stderr
    assert "3 episode(s), 45 frames, 45 decoded through LeRobot" in check.stdout, check.stdout
