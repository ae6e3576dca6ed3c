"""Fleet path: bags, staging and output on a real S3-compatible HTTP endpoint (moto's server on
loopback) through s3fs, converted on an existing Dask cluster of worker processes (``--dask-address``),
loaded by LeRobot; the credentials appear in no output, log, dataset or staged object."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import s3fs
from distributed import get_task_stream

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.runners import dask_runner
from tests.dask_cluster import dask_cluster
from tests.helpers import REPO, SAMPLE_CONTRACT
from tests.s3 import KEY_ID, SECRET

CREDENTIALS = (SECRET.encode(), KEY_ID.encode())


def _leaked(blob: bytes) -> list[bytes]:
    return [c for c in CREDENTIALS if c in blob]


@pytest.mark.slow
def test_s3_bags_staging_and_output_on_an_existing_dask_cluster(
    tmp_path: Path, s3_env: dict[str, str], capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    fs = s3fs.S3FileSystem(endpoint_url=s3_env["AWS_ENDPOINT_URL"])
    fs.mkdir("fleet")
    write_episode_bag(tmp_path / "ep_mcap", "mcap", EpisodeSpec(duration_s=1.0, seed=1))
    write_episode_bag(tmp_path / "ep_ros1.bag", "ros1", EpisodeSpec(duration_s=1.0, seed=2, task="stack"))
    fs.put(str(tmp_path / "ep_mcap"), "fleet/2026-11-20/ep_mcap", recursive=True)
    fs.put_file(str(tmp_path / "ep_ros1.bag"), "fleet/2026-11-20/ep_ros1.bag")
    fs.pipe("fleet/manifest.yaml", b"bags:\n  - uri: 2026-11-20/*\n")
    # The workers inherit the AWS variables (as `dask worker` would from its host) and log at INFO
    # to this process's stderr, where capfd reads them.
    monkeypatch.setenv("PREFECT_LOGGING_LEVEL", "INFO")
    monkeypatch.setenv("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "INFO")
    with dask_cluster() as (scheduler_address, client):
        workers = client.run(os.getpid)  # worker address -> pid
        env = {**os.environ, **s3_env, "BAGPORT_DEBUG": "0"}
        with get_task_stream(client) as stream:
            proc = subprocess.run(
                [
                    sys.executable, "-m", "flows.cli", "convert",
                    "--manifest", "s3://fleet/manifest.yaml",
                    "--contract", str(SAMPLE_CONTRACT),
                    "--output", "s3://fleet/datasets/sample",
                    "--staging", "s3://fleet/staging",
                    "--runner", "dask", "--dask-address", scheduler_address,
                    "--keep-staging", "--verbose",
                ],
                capture_output=True, text=True, check=False, cwd=REPO, env=env,
            )  # fmt: skip
        worker_logs = json.dumps(client.get_worker_logs()).encode()  # type: ignore[no-untyped-call]
    assert proc.returncode == 0, proc.stderr[-3000:]
    # Both episodes ran as tasks on the cluster's worker processes, not in the CLI's process.
    ran = [t for t in stream.data if str(t["key"]).startswith("convert_episode_task-")]
    assert len(ran) == 2
    assert {t["worker"] for t in ran} <= set(workers)
    assert os.getpid() not in workers.values()
    # So did writing the output files (the data file and each camera's video file: one task each, their
    # files uploaded from the workers into the write's staged prefix); the commit runs in the flow.
    wrote = [t for t in stream.data if str(t["key"]).startswith("write_file_task-")]
    assert len(wrote) == 3 and {t["worker"] for t in wrote} <= set(workers)
    local = tmp_path / "downloaded"
    fs.get("fleet/datasets/sample", str(local), recursive=True)
    report = validate_dataset(local, repo_id="test/s3")
    assert report.episodes == 2
    run = json.loads((local / "meta/provenance/run.json").read_text())
    assert [e["bag_uri"] for e in run["episodes"]] == [
        "s3://fleet/2026-11-20/ep_mcap",
        "s3://fleet/2026-11-20/ep_ros1.bag",
    ]
    access = {e["bag_uri"]: e["bag_read"]["access"] for e in run["episodes"]}
    assert access == {
        "s3://fleet/2026-11-20/ep_mcap": "ranged",
        "s3://fleet/2026-11-20/ep_ros1.bag": "download",
    }
    # Credentials are never logged nor written: not by the CLI, the workers, into the dataset
    # (meta/, provenance, the QA report, data and videos) nor into the staged episodes.
    workers_out = capfd.readouterr()
    assert "frames staged at s3://fleet/staging" in workers_out.err  # the workers' INFO logs were captured
    for name, text in {
        "CLI stdout": proc.stdout,
        "CLI stderr": proc.stderr,
        "worker stdout": workers_out.out,
        "worker stderr": workers_out.err,
    }.items():
        assert not _leaked(text.encode()), name
    assert not _leaked(worker_logs)
    objects = fs.find("fleet/datasets/sample") + fs.find("fleet/staging")
    assert any(o.endswith("meta/provenance/run.json") for o in objects)
    assert any("/meta/qa/" in o and o.endswith(".html") for o in objects)
    assert sum(o.endswith("episode.json") for o in objects) == 2  # the kept staging store
    assert {o: found for o in objects if (found := _leaked(fs.cat_file(o)))} == {}


def test_dask_runner_starts_a_local_cluster_or_connects_to_an_address() -> None:
    """The flow-started local cluster: the same runner with cluster settings (run end to end by the
    benchmark's bagport-dask1/2 tools); with an address, the runner connects instead."""
    local = dask_runner(ConvertConfig(manifest="m.yaml", contract="c.yaml", output="out"), workers=3)
    assert local.address is None  # type: ignore[attr-defined]
    assert local.cluster_kwargs == {  # type: ignore[attr-defined]
        "n_workers": 3,
        "threads_per_worker": 1,
        "processes": True,
        "dashboard_address": None,
        "scheduler_kwargs": {"dashboard_address": ":0"},
    }
    config = ConvertConfig(
        manifest="m.yaml", contract="c.yaml", output="out", runner="dask", dask_address="tcp://h:8786"
    )
    remote = dask_runner(config, workers=3)
    assert remote.address == "tcp://h:8786"  # type: ignore[attr-defined]


@pytest.mark.slow
def test_the_flow_starts_its_own_local_dask_cluster(tmp_path: Path) -> None:
    """``--runner dask`` without an address, on one machine: the flow starts a LocalCluster of worker
    processes for the run (and closes it), and the dataset loads in LeRobot."""
    for seed in (1, 2):
        write_episode_bag(tmp_path / f"bags/ep{seed}", "mcap", EpisodeSpec(duration_s=1.0, seed=seed))
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "INFO"}
    with socket.socket() as dask_default_port:  # another run's cluster on Dask's default port 8787
        with contextlib.suppress(OSError):  # a process of the machine's has it: as good
            dask_default_port.bind(("127.0.0.1", 8787))
            dask_default_port.listen()
        proc = _convert_on_own_cluster(tmp_path, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    logs = proc.stdout + proc.stderr
    assert "Creating a new Dask cluster with `distributed.deploy.local.LocalCluster`" in logs
    assert "already in use" not in logs  # the cluster took a free port, not 8787, without a warning
    assert validate_dataset(tmp_path / "ds", repo_id="test/dask-local").episodes == 2


def _convert_on_own_cluster(tmp_path: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable, "-m", "flows.cli", "convert",
            "--glob", str(tmp_path / "bags/*"),
            "--contract", str(SAMPLE_CONTRACT),
            "--output", str(tmp_path / "ds"),
            "--runner", "dask", "--workers", "2", "--verbose",
        ],
        capture_output=True, text=True, check=False, cwd=REPO, env=env,
    )  # fmt: skip
