"""`bagport convert --append` killed mid-commit (BAGPORT_CRASH_AT, a real SIGKILL), then `bagport validate`
says "needs repair", `bagport repair` says what it did, and the re-run appends exactly once."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from bagport.dataset.validate import validate_dataset
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT

pytestmark = pytest.mark.slow

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)


def _bagport(root: Path, *args: str, crash_at: str | None = None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_API_URL", "BAGPORT_CRASH_AT")}
    env["TMPDIR"] = str(root / "tmp")  # the run's temporary folders, to check none is left over
    if crash_at is not None:
        env["BAGPORT_CRASH_AT"] = crash_at
    out, err = root / "stdout.txt", root / "stderr.txt"  # files: an orphaned server would hold a pipe open
    with out.open("w") as stdout, err.open("w") as stderr:
        process = subprocess.Popen(
            [sys.executable, "-m", "flows.cli", *args], cwd=REPO, env=env, text=True,
            stdout=stdout, stderr=stderr, start_new_session=True,
        )  # fmt: skip
        try:
            process.wait(timeout=600)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)  # a killed run's Prefect server is orphaned: end it
    return subprocess.CompletedProcess(process.args, process.returncode, out.read_text(), err.read_text())


def _convert(root: Path, manifest: str, crash_at: str | None = None) -> subprocess.CompletedProcess[str]:
    return _bagport(
        root, "convert", "--manifest", str(root / manifest), "--contract", str(SAMPLE_CONTRACT),
        "--output", str(root / "ds"), "--codec", str(root / "codec.yaml"), "--runner", "thread",
        "--workers", "1", "--append", "--quiet", crash_at=crash_at,
    )  # fmt: skip


def _one_appended(root: Path) -> None:
    """Bags ``a`` and ``b``, manifests ``one.yaml`` (a) and ``two.yaml`` (a, b), and ``a`` appended to ``ds``."""
    (root / "tmp").mkdir()
    for i, name in enumerate(("a", "b")):
        write_episode_bag(root / name, "mcap", EpisodeSpec(duration_s=0.6, seed=i, cameras=CAMERAS))
    (root / "one.yaml").write_text("bags:\n  - uri: a\n")
    (root / "two.yaml").write_text("bags:\n  - uri: a\n  - uri: b\n")
    (root / "codec.yaml").write_text(yaml.safe_dump(FAST_CODEC))
    assert _convert(root, "one.yaml").returncode == 0


def test_an_append_killed_mid_commit_is_reported_repaired_and_appended_once(tmp_path: Path) -> None:
    _one_appended(tmp_path)

    killed = _convert(tmp_path, "two.yaml", crash_at="local.append.moved")
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    assert (tmp_path / "ds/data/chunk-000/file-001.parquet").exists()  # moved in, not yet described

    checked = _bagport(tmp_path, "validate", str(tmp_path / "ds"))
    assert checked.returncode == 2
    assert "needs repair" in checked.stderr and "bagport repair" in checked.stderr

    repaired = _bagport(tmp_path, "repair", str(tmp_path / "ds"))
    assert repaired.returncode == 0, repaired.stderr
    assert "rolled back an append" in repaired.stdout and "removed 3 new file(s)" in repaired.stdout
    assert "nothing to repair" in _bagport(tmp_path, "repair", str(tmp_path / "ds")).stdout

    again = _convert(tmp_path, "two.yaml")
    assert again.returncode == 0, again.stderr[-2000:]
    report = validate_dataset(tmp_path / "ds", repo_id="test/repair")
    assert report.episodes == 2
    rows = [pq.read_metadata(p).num_rows for p in sorted((tmp_path / "ds/data").rglob("*.parquet"))]
    assert sum(rows) == report.frames  # every data row described by meta/, none twice
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    assert [p.name for p in (tmp_path / "tmp").iterdir() if p.name.startswith("bagport-")] == []


def test_an_append_killed_after_its_commit_leaves_staged_episodes_the_next_append_removes(
    tmp_path: Path,
) -> None:
    """Killed after the commit's last step, before the run removed its staged episodes: the dataset has the
    new episode; the next append (with nothing new) removes the leftovers and says so."""
    _one_appended(tmp_path)
    staging = tmp_path / "ds.staging" / "episodes"

    killed = _convert(tmp_path, "two.yaml", crash_at="local.append.cleaned")
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    left = sorted(p.name for p in staging.iterdir())
    assert len(left) == 1 and left[0].startswith("b-")

    again = _convert(tmp_path, "two.yaml")
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"removed 1 staged episode(s) from {tmp_path / 'ds.staging'}" in again.stderr
    assert "nothing to do" in again.stderr
    assert list(staging.iterdir()) == []
    assert validate_dataset(tmp_path / "ds", repo_id="test/repair").episodes == 2
