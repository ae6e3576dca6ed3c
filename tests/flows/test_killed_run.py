"""A run killed outright (SIGKILL, the OOM killer) leaves nothing running: its temporary Prefect server,
its pool workers and their forkserver end once it is gone, although it never stopped them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil

from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

BAGS = 24
CAMERAS = (  # the sample contract's cameras
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)


def _tree(process: psutil.Process) -> list[psutil.Process]:
    try:
        return process.children(recursive=True)
    except psutil.Error:
        return []


def _pool(processes: list[psutil.Process]) -> list[psutil.Process]:
    """The pool's processes among a run's: its forkserver (a fork of the CLI, so it has the CLI's command
    line, as have the workers forked from it) and its workers; not the server or the resource tracker."""
    pool = []
    for process in processes:
        try:
            command = " ".join(process.cmdline())
        except psutil.Error:
            continue
        if "uvicorn" not in command and "resource_tracker" not in command:
            pool.append(process)
    return pool


def test_a_killed_run_leaves_no_server_worker_or_forkserver_behind(tmp_path: Path) -> None:
    for i in range(BAGS):
        write_episode_bag(
            tmp_path / f"ep{i:02d}", "mcap", EpisodeSpec(duration_s=1.0, seed=i, cameras=CAMERAS)
        )
    (tmp_path / "manifest.yaml").write_text("bags:\n" + "".join(f"  - uri: ep{i:02d}\n" for i in range(BAGS)))
    codec = tmp_path / "codec.yaml"
    codec.write_text("".join(f"{key}: {value}\n" for key, value in FAST_CODEC.items()))
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}  # its own temporary server
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--manifest", str(tmp_path / "manifest.yaml"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "ds"), "--codec", str(codec),
        "--runner", "process", "--workers", "2", "--quiet",
    ]  # fmt: skip
    with (tmp_path / "stderr.txt").open("wb") as stderr:
        run = psutil.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr)
        started: list[psutil.Process] = []
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and run.poll() is None:  # until its workers convert
                if len(_pool(_tree(run))) >= 3:
                    break
                time.sleep(0.1)
            started = _tree(run)
            assert run.poll() is None, "the run ended before its workers started: give it more bags"
            assert any("uvicorn" in " ".join(p.cmdline()) for p in started)  # the server, and
            assert len(_pool(started)) >= 3  # forkserver + workers
            assert not [p for p in started if "multiprocessing.forkserver" in " ".join(p.cmdline())]  # forked
            os.kill(run.pid, signal.SIGKILL)  # the run alone, not its process group
            run.wait()
            gone, alive = psutil.wait_procs(started, timeout=30)
            assert not alive, [" ".join(p.cmdline())[:80] for p in alive]
            assert len(gone) == len(started)
        finally:  # whatever the outcome, by pid: the run and what it had started
            for process in [run, *_tree(run), *started]:
                if process.is_running():
                    process.kill()
