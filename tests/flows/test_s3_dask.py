"""Fleet path: bags, staging and output on a real S3-compatible HTTP endpoint (moto's server on
loopback) through s3fs, converted on a Dask cluster of worker processes, loaded by LeRobot."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import s3fs

from bagport.dataset.validate import validate_dataset
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import REPO, SAMPLE_CONTRACT
from tests.s3 import SECRET

pytestmark = pytest.mark.slow


def test_s3_bags_staging_and_output_on_dask(tmp_path: Path, s3_env: dict[str, str]) -> None:
    fs = s3fs.S3FileSystem(endpoint_url=s3_env["AWS_ENDPOINT_URL"])
    fs.mkdir("fleet")
    write_episode_bag(tmp_path / "ep_mcap", "mcap", EpisodeSpec(duration_s=1.0, seed=1))
    write_episode_bag(tmp_path / "ep_ros1.bag", "ros1", EpisodeSpec(duration_s=1.0, seed=2, task="stack"))
    fs.put(str(tmp_path / "ep_mcap"), "fleet/2026-11-20/ep_mcap", recursive=True)
    fs.put_file(str(tmp_path / "ep_ros1.bag"), "fleet/2026-11-20/ep_ros1.bag")
    fs.pipe("fleet/manifest.yaml", b"bags:\n  - uri: 2026-11-20/*\n")
    env = {**os.environ, **s3_env, "BAGPORT_DEBUG": "0"}
    proc = subprocess.run(
        [
            sys.executable, "-m", "flows.cli", "convert",
            "--manifest", "s3://fleet/manifest.yaml",
            "--contract", str(SAMPLE_CONTRACT),
            "--output", "s3://fleet/datasets/sample",
            "--staging", "s3://fleet/staging",
            "--runner", "dask", "--workers", "2",
        ],
        capture_output=True, text=True, check=False, cwd=REPO, env=env,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert fs.exists("fleet/datasets/sample/meta/info.json")
    assert not fs.exists("fleet/staging/episodes")  # staging cleaned after success
    local = tmp_path / "downloaded"
    fs.get("fleet/datasets/sample", str(local), recursive=True)
    report = validate_dataset(local, repo_id="test/s3")
    assert report.episodes == 2
    run = (local / "meta/provenance/run.json").read_text()
    assert [e["bag_uri"] for e in json.loads(run)["episodes"]] == [
        "s3://fleet/2026-11-20/ep_mcap",
        "s3://fleet/2026-11-20/ep_ros1.bag",
    ]
    assert SECRET not in run  # credentials are never written into provenance
    access = {e["bag_uri"]: e["bag_read"]["access"] for e in json.loads(run)["episodes"]}
    assert access == {
        "s3://fleet/2026-11-20/ep_mcap": "ranged",
        "s3://fleet/2026-11-20/ep_ros1.bag": "download",
    }
