"""Crash and resume: a conversion killed half way (SIGKILL, no clean-up) and run again converts only
the episodes that had not finished; a run after that does no episode work at all."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from bagport.dataset.validate import validate_dataset
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT

pytestmark = pytest.mark.slow

BAGS = 6
CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)


def _convert(root: Path, *extra: str) -> subprocess.Popen[str]:
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--manifest", str(root / "manifest.yaml"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(root / "ds"), "--codec", str(root / "codec.yaml"),
        "--runner", "thread", "--workers", "1", "--keep-staging", "--quiet", *extra,
    ]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}  # its own temporary server
    return subprocess.Popen(
        command, cwd=REPO, env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        start_new_session=True,  # one process group with its Prefect server: killed together
    )  # fmt: skip


def _staged(root: Path) -> dict[str, int]:
    """Finished staged episodes: completion marker -> its modification time."""
    return {
        p.parent.name: p.stat().st_mtime_ns for p in (root / "ds.staging").glob("episodes/*/episode.json")
    }


def test_a_killed_run_resumes_with_the_remaining_episodes_only(tmp_path: Path) -> None:
    for i in range(BAGS):
        write_episode_bag(tmp_path / f"ep{i}", "mcap", EpisodeSpec(duration_s=1.5, seed=i, cameras=CAMERAS))
    (tmp_path / "manifest.yaml").write_text("bags:\n" + "".join(f"  - uri: ep{i}\n" for i in range(BAGS)))
    (tmp_path / "codec.yaml").write_text(yaml.safe_dump(FAST_CODEC))

    first = _convert(tmp_path)
    deadline = time.monotonic() + 240
    while len(_staged(tmp_path)) < 2 and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(first.pid, signal.SIGKILL)  # the flow and its Prefect server, mid-run
    first.communicate()
    before_resume = _staged(tmp_path)
    assert 2 <= len(before_resume) < BAGS, "the first run was not killed half way"
    assert not (tmp_path / "ds").exists()  # nothing published by the killed run

    second = _convert(tmp_path)
    _, err = second.communicate(timeout=600)
    assert second.returncode == 0, err[-3000:]
    after_resume = _staged(tmp_path)
    assert len(after_resume) == BAGS
    # the episodes finished before the kill were reused, not converted again
    assert {k: after_resume[k] for k in before_resume} == before_resume
    report = validate_dataset(tmp_path / "ds", repo_id="test/resume")
    assert report.episodes == BAGS

    # re-running the same flow is a cache hit: no episode is converted again
    third = _convert(tmp_path, "--overwrite")
    _, err = third.communicate(timeout=600)
    assert third.returncode == 0, err[-3000:]
    assert _staged(tmp_path) == after_resume
    assert validate_dataset(tmp_path / "ds", repo_id="test/resume").episodes == BAGS
