"""A smoke run of the benchmark harness at a tiny scale, so `make bench` cannot rot.

Times are not checked (CI times nothing); what is checked: every tool runs on the same generated
bags, the report table is written between its markers, and the LeRobot-writer baseline and bagport
both produce datasets LeRobot loads with the same number of frames per episode (give or take the
first tick, which each anchors differently).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.slow


def test_bench_smoke_run_writes_a_report_and_comparable_datasets(tmp_path: Path) -> None:
    report = tmp_path / "BENCHMARKS.md"
    report.write_text(
        "# Benchmarks\n\nprose above\n\n<!-- results:start -->\nold\n<!-- results:end -->\n\nprose below\n"
    )
    results = tmp_path / "results.json"
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    done = subprocess.run(
        [sys.executable, str(REPO / "bench" / "run.py"), "--workloads", "W3", "--scale", "0.01", "--runs", "1",
         "--data", str(tmp_path / "data"), "--report", str(report), "--results", str(results), "--keep-outputs"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    measured = json.loads(results.read_text())
    cells = measured["workloads"]["W3"]["tools"]
    assert set(cells) == {"bagport", "lerobot", "lerobot-streaming", "floor"}
    for cell in cells.values():
        assert cell["wall_s"] > 0 and cell["cpu_s"] > 0 and cell["peak_rss_mb"] > 50 and cell["output_mb"] > 0
    text = report.read_text()
    assert "prose above" in text and "prose below" in text and "old" not in text
    assert text.count("| bagport |") == 1 and "| floor |" in text and "x the floor" in text

    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    out = tmp_path / "data" / "out"
    ours = LeRobotDataset("bench/bagport", root=out / "W3-bagport")
    theirs = LeRobotDataset("bench/baseline", root=out / "W3-lerobot")
    assert ours.num_episodes == theirs.num_episodes == 2
    for episode in range(2):
        length = {
            name: int(ds.meta.episodes[episode]["length"])
            for name, ds in (("ours", ours), ("theirs", theirs))
        }
        assert abs(length["ours"] - length["theirs"]) <= 1, length
    last = ours[len(ours) - 1]
    assert tuple(last["observation.images.front"].shape) == (3, 96, 128)


def test_measure_survives_a_run_that_writes_more_than_a_pipe_holds_to_stderr(tmp_path: Path) -> None:
    """An encoder banner per episode once filled the unread stderr pipe and hung the run."""
    from bench.run import measure  # noqa: PLC0415 - bench is not a dependency of the other tests

    noisy = [sys.executable, "-c", "import sys; sys.stderr.write('x' * 1_000_000)"]
    measured = measure(noisy, tmp_path / "out")
    assert measured["wall_s"] > 0
    failing = [sys.executable, "-c", "import sys; sys.stderr.write('y' * 1_000_000 + 'the end'); sys.exit(3)"]
    with pytest.raises(RuntimeError, match=r"(?s)failed \(3\):\n.*the end$"):
        measure(failing, tmp_path / "out")


def test_bagport_server_runs_against_one_running_server_whose_cpu_is_counted(tmp_path: Path) -> None:
    """``bagport-server``: the runs see the harness's server through ``PREFECT_API_URL``, and the CPU the
    server spends on a run is counted in the run's ``cpu_s``."""
    from bench.run import measure, running_server  # noqa: PLC0415 - bench is not a dependency of the other tests

    with running_server(["bagport"]) as none:
        assert none is None  # only bagport-server starts one
    calls = (
        "import os, urllib.request\n"
        "url = os.environ['PREFECT_API_URL']\n"
        "for _ in range(200): urllib.request.urlopen(url + '/admin/version').read()\n"
        "print(url)\n"
    )
    with running_server(["floor", "bagport-server"]) as server:
        assert server is not None
        measured = measure([sys.executable, "-c", calls], tmp_path / "out", server=server)
    assert measured["server_cpu_s"] > 0
    assert measured["cpu_s"] >= measured["server_cpu_s"]
