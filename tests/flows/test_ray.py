"""``--runner ray``: episodes converted as Ray tasks in Ray worker processes (prefect-ray), the
address only with its runner, and a clear error without the extra."""

from __future__ import annotations

import logging
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import psutil
import pydantic
import pytest
from prefect.settings import PREFECT_LOGGING_LEVEL, temporary_settings

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from flows.cli import main
from flows.runners import RayMissingError, ray_runner
from tests.helpers import REPO, SAMPLE_CONTRACT

EPISODES = 3
# Ray prefixes what its workers log with the task's name and the worker's pid.
FINISHED = re.compile(
    r"\(convert-episode pid=(\d+)\).*Task run 'convert (\S+)' - Finished in state Completed"
)


def _config(**fields: str) -> ConvertConfig:
    return ConvertConfig(manifest="m.yaml", contract="c.yaml", output="out", **fields)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("runner", "field", "address"),
    [
        ("process", "ray_address", "auto"),
        ("dask", "ray_address", "ray://head:10001"),
        ("ray", "dask_address", "tcp://scheduler:8786"),
    ],
    ids=["ray-address-on-process", "ray-address-on-dask", "dask-address-on-ray"],
)
def test_an_address_needs_its_runner(runner: str, field: str, address: str) -> None:
    with pytest.raises(pydantic.ValidationError, match=f"{field} '{address}' is only used with runner"):
        _config(runner=runner, **{field: address})


def test_ray_address_on_the_cli_without_runner_ray_exits_2(capfd: pytest.CaptureFixture[str]) -> None:
    code = main(
        [
            "convert",
            "--manifest",
            "m.yaml",
            "--contract",
            "c.yaml",
            "--output",
            "out",
            "--ray-address",
            "auto",
        ]
    )
    assert code == 2
    err = capfd.readouterr().err
    assert "ray_address 'auto' is only used with runner 'ray', not 'process'" in err
    assert "add --runner ray" in err
    assert "Traceback" not in err


def test_runner_ray_without_the_extra_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "prefect_ray", None)  # import prefect_ray -> ImportError
    with pytest.raises(RayMissingError, match=r"pip install 'bagport\[ray\]'"):
        ray_runner(_config(runner="ray"), workers=2)


@pytest.mark.parametrize(
    ("prefect_level", "ray_level"),
    [("INFO", logging.INFO), ("WARNING", logging.WARNING), ("ERROR", logging.ERROR)],
    ids=["verbose", "default", "quiet"],
)
@pytest.mark.parametrize("address", ["", "auto", "ray://head:10001"])
def test_ray_logs_at_the_level_of_the_run(
    monkeypatch: pytest.MonkeyPatch, prefect_level: str, ray_level: int, address: str
) -> None:
    """Ray's driver lines follow Prefect's level, which --verbose / --quiet set (flows/cli.py) and a
    deployment's worker leaves at INFO: its 'Started a local Ray instance' and 'Connecting to existing Ray
    cluster' with --verbose (and in a deployment's run, tests/flows/test_deployments.py), not by default."""
    monkeypatch.setenv("RAY_AUTH_MODE", "probe")
    monkeypatch.delenv("RAY_AUTH_MODE")  # restored (unset) after the test, whatever ray_runner sets
    fields = {"ray_address": address} if address else {}
    with temporary_settings(updates={PREFECT_LOGGING_LEVEL: prefect_level}):
        runner = ray_runner(_config(runner="ray", **fields), workers=2)
    assert runner.init_kwargs["logging_level"] == ray_level  # type: ignore[attr-defined]
    # a local instance bagport starts says its auth mode (Ray's default), so Ray does not warn about it
    assert os.environ.get("RAY_AUTH_MODE") == (None if address else "token")


@pytest.mark.slow
@pytest.mark.xdist_group("ray")  # one local Ray instance at a time under xdist
def test_convert_on_a_local_ray_instance(tmp_path: Path) -> None:
    bags = tmp_path / "bags"
    assert main(["synth", "--out", str(bags), "--episodes", str(EPISODES), "--duration", "1"]) == 0
    out = tmp_path / "dataset"
    # Ray's sockets and logs in a folder of this test (short: Unix socket paths are limited),
    # and every worker log line, not Ray's "[repeated 2x across cluster]" summaries.
    ray_tmp = tempfile.mkdtemp(prefix="bagport-ray-")
    env = {**os.environ, "RAY_TMPDIR": ray_tmp, "RAY_DEDUP_LOGS": "0", "BAGPORT_DEBUG": "0"}
    with subprocess.Popen(
        [
            sys.executable, "-m", "flows.cli", "convert",
            "--manifest", str(bags / "manifest.yaml"),
            "--contract", str(SAMPLE_CONTRACT),
            "--output", str(out),
            "--runner", "ray", "--workers", "2", "--verbose",
        ],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env,
    ) as proc:  # fmt: skip
        stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr[-3000:]
    assert "Started a local Ray instance" in stderr  # --verbose: Ray's INFO lines
    assert "Token authentication is enabled for this Ray cluster" not in stderr  # its mode said explicitly
    ran = {name: int(pid) for pid, name in FINISHED.findall(stdout + stderr)}
    # Every episode ran as a Ray task in a Ray worker process, not in the CLI's.
    assert sorted(ran) == ["episode_000", "episode_001", "episode_002.bag"], stderr[-3000:]
    assert proc.pid not in ran.values()
    assert len(set(ran.values())) <= 2  # num_cpus = --workers: at most 2 workers, one episode each
    report = validate_dataset(out, repo_id="test/ray")
    assert report.episodes == EPISODES
    # The run shut its Ray instance down: no raylet, GCS or worker of it is left.
    left = [
        p.info["pid"]
        for p in psutil.process_iter(["pid", "cmdline"])
        if ray_tmp in " ".join(p.info["cmdline"] or ())
    ]
    assert not left, f"Ray processes left running: {left}"
    shutil.rmtree(ray_tmp)
