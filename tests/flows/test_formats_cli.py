"""Acceptance of ``--format``: one fleet (two good bags, one broken) converted through the real Prefect
engine into every format at once; the outputs agree frame by frame, each holds provenance, the broken
bag is left out of all of them alike, and a re-run rebuilds every output from the staged episodes
without reading a bag again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from bagport.formats.hdf5 import hdf5_path
from bagport.formats.robodm import trajectory_class
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT
from tests.lerobot_frames import LeRobotFrame, lerobot_frames

pytestmark = pytest.mark.slow

FORMATS = "lerobot,robodm,hdf5"
CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)


def _convert(root: Path, *extra: str) -> int:
    """One run in its own process (with its own temporary Prefect server), as a user runs it."""
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--manifest", str(root / "manifest.yaml"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(root / "ds"), "--codec", str(root / "codec.yaml"),
        "--format", FORMATS, "--runner", "thread", "--workers", "2", "--keep-staging", "--quiet", *extra,
    ]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    done = subprocess.run(
        command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    return done.returncode


def _staged(root: Path) -> dict[str, int]:
    return {
        p.parent.name: p.stat().st_mtime_ns for p in (root / "ds.staging").glob("episodes/*/episode.json")
    }


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[LeRobotFrame]]:
    root = tmp_path_factory.mktemp("formats")
    for i, duration_s in enumerate((0.6, 0.9)):
        write_episode_bag(
            root / f"ep{i}",
            "mcap",
            EpisodeSpec(duration_s=duration_s, seed=i, cameras=CAMERAS, task=f"task {i}"),
        )
    (root / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)  # not a readable bag
    manifest = {
        "bags": [
            {"uri": "ep0", "task": "pick", "metadata": {"operator": "ana"}},
            {"uri": "broken.mcap", "task": "place"},
            {"uri": "ep1", "task": "place"},
        ]
    }
    (root / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    (root / "codec.yaml").write_text(yaml.safe_dump(FAST_CODEC))
    assert _convert(root) == 1  # a bag was excluded
    return root, list(lerobot_frames(root / "ds"))


def test_every_format_holds_the_same_episodes_with_provenance(fleet: tuple[Path, list[LeRobotFrame]]) -> None:
    root, frames = fleet
    for out in (root / "ds", root / "ds.hdf5", root / "ds.robodm"):
        run = json.loads((out / "meta/provenance/run.json").read_text())
        assert [e["bag_uri"] for e in run["episodes"]] == [str(root / "ep0"), str(root / "ep1")], out
        assert [e["bag_uri"] for e in run["excluded"]] == [str(root / "broken.mcap")], out
        assert run["episodes"][0]["metadata"] == {"operator": "ana"}
        assert all(e["alignment"] and e["qa"]["verdict"] for e in run["episodes"]), out  # read back
        assert (out / "meta/provenance/chunk-000/file-000.parquet").is_file()
    assert sorted(p.name for p in (root / "ds.hdf5").glob("*.hdf5")) == ["episode_0.hdf5", "episode_1.hdf5"]
    assert sorted(p.name for p in (root / "ds.robodm").glob("*.vla")) == ["episode_0.vla", "episode_1.vla"]
    assert {f.episode_index for f in frames} == {0, 1}


def test_robodm_agrees_with_lerobot_frame_by_frame(fleet: tuple[Path, list[LeRobotFrame]]) -> None:
    root, frames = fleet
    trajectory = trajectory_class()
    loaded = [trajectory(str(root / "ds.robodm" / f"episode_{i}.vla"), mode="r").load() for i in range(2)]
    assert [json.loads(data["episode"][0])["tasks"] for data in loaded] == [["task 0"], ["task 1"]]
    assert json.loads(loaded[0]["episode"][0])["metadata"] == {"operator": "ana"}
    assert sum(len(data["action"]) for data in loaded) == len(frames)
    for frame in frames:
        data, n = loaded[frame.episode_index], frame.frame_index
        np.testing.assert_array_equal(data["observation.state"][n], frame.vectors["observation.state"])
        np.testing.assert_array_equal(data["action"][n], frame.vectors["action"])
        assert data["timestamp"][n] == np.float32(frame.timestamp)
        for key, image in frame.images.items():
            assert np.abs(data[key][n].astype(int) - image.astype(int)).max() <= 1


def test_hdf5_agrees_with_lerobot_frame_by_frame(fleet: tuple[Path, list[LeRobotFrame]]) -> None:
    root, frames = fleet
    files = [h5py.File(root / "ds.hdf5" / f"episode_{i}.hdf5", "r") for i in range(2)]
    try:
        assert [f.attrs["task"] for f in files] == ["task 0", "task 1"]
        assert sum(f["action"].shape[0] for f in files) == len(frames)
        for frame in frames:
            f, n = files[frame.episode_index], frame.frame_index
            np.testing.assert_array_equal(f["observations/qpos"][n], frame.vectors["observation.state"])
            np.testing.assert_array_equal(f["action"][n], frame.vectors["action"])
            assert f["timestamp"][n] == np.float32(frame.timestamp)
            for key, image in frame.images.items():
                assert np.abs(f[hdf5_path(key)][n].astype(int) - image.astype(int)).max() <= 1
    finally:
        for f in files:
            f.close()


def test_a_rerun_rebuilds_every_output_from_staging_without_reading_bags(
    fleet: tuple[Path, list[LeRobotFrame]],
) -> None:
    root, frames = fleet
    staged = _staged(root)
    assert len(staged) == 2
    (root / "ds.hdf5" / "episode_1.hdf5").unlink()  # as a partial output from an interrupted run would be
    (root / "ds.robodm" / "episode_0.vla").unlink()
    killed_build = root / ".ds.hdf5.tmp-0badcafe"  # what a run killed while building the HDF5 output leaves
    killed_build.mkdir()
    (killed_build / "episode_0.hdf5").write_bytes(b"partial")
    assert _convert(root, "--overwrite") == 1
    assert _staged(root) == staged  # the staged episodes were reused, none converted again
    with h5py.File(root / "ds.hdf5" / "episode_1.hdf5", "r") as f:
        assert f["action"].shape[0] == sum(fr.episode_index == 1 for fr in frames)
    assert (root / "ds.robodm" / "episode_0.vla").is_file()
    assert not killed_build.exists()  # removed by the re-run's recovery, never swapped in
