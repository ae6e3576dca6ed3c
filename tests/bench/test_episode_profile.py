"""The per-episode profile runs on a tiny W3 and counts what a worker repeats per episode."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from bagport.bags import open_bag
from bench.episode_profile import main
from tests.conftest import REPO

_MAKE = (
    "import sys; from pathlib import Path; from bench.workloads import WORKLOADS, ensure_workload; "
    "print(ensure_workload(WORKLOADS['W3'].scaled(0.01), Path(sys.argv[1]), workers=1))"
)
"""Bags written in a fresh process (the workload writer forks a pool: not from this threaded one)."""


def test_profile_reports_cpu_steps_and_counts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    made = subprocess.run(
        [sys.executable, "-c", _MAKE, str(tmp_path / "data")],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    )
    workload = Path(made.stdout.strip())
    main([str(workload), "--episodes", "1", "--top", "0"])
    out = capsys.readouterr().out
    assert re.search(r"1 episodes: \d+\.\d+ CPU s \(\d+\.\d+ on the main thread", out)
    assert re.search(r"\d+\.\d+ ms  pass 2: read, deserialise, decode JPEG", out)
    assert "contract parsed: 0 per episode" in out  # parsed once per process, by the warm-up episode
    assert "parquet tables read back: 0 per episode" in out  # a short episode's stats need no read back
    messages = re.search(r"messages read from the bag \(both passes; \+1 per read\): (\d+) per episode", out)
    with open_bag(str(workload / "ep001")) as bag:
        in_bag = bag.info.message_count
    # read once (cProfile counts a generator's final resume too: one more call per read)
    assert messages is not None and 0 < int(messages.group(1)) <= in_bag + 1
