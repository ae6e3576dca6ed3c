"""A real `prefect server start` (SQLite) watches a conversion: flow run, one task run per episode, artifacts."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import (
    ArtifactFilter,
    ArtifactFilterFlowRunId,
    FlowRunFilter,
    FlowRunFilterId,
)
from prefect.settings import PREFECT_API_URL, temporary_settings

from bagport.synth import write_sample_fleet
from tests.helpers import REPO, SAMPLE_CONTRACT
from tests.prefect_server import prefect_server as running_prefect_server

pytestmark = pytest.mark.slow


@pytest.fixture
def prefect_server(tmp_path: Path) -> Iterator[tuple[str, dict[str, str]]]:
    with running_prefect_server(tmp_path) as server:
        yield server


async def _inspect(api_url: str) -> tuple[list[str], list[str], dict[str, object]]:
    async with get_client() as client:
        assert str(client.api_url).rstrip("/") == api_url
        flow_runs = await client.read_flow_runs()
        assert len(flow_runs) == 1
        run = flow_runs[0]
        task_runs = await client.read_task_runs(
            flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[run.id]))
        )
        artifacts = await client.read_artifacts(
            artifact_filter=ArtifactFilter(flow_run_id=ArtifactFilterFlowRunId(any_=[run.id]))
        )
        return (
            [str(run.state_name)],
            sorted(f"{t.name} {' '.join(sorted(t.tags))}" for t in task_runs),
            {str(a.key): a.data for a in artifacts if a.key},
        )


@pytest.mark.parametrize("runner", ["thread", "process"])
def test_conversion_is_visible_through_the_prefect_api(
    tmp_path: Path, prefect_server: tuple[str, dict[str, str]], runner: str
) -> None:
    """Under each runner every task run carries its own bag's tag (the process runner once tagged
    every task run with the first bag's: issue 16, finding 2)."""
    api_url, env = prefect_server
    write_sample_fleet(tmp_path / "bags", episodes=2, duration_s=1.0)
    out = tmp_path / "dataset"
    proc = subprocess.run(
        [sys.executable, "-m", "flows.cli", "convert", "--manifest", str(tmp_path / "bags" / "manifest.yaml"),
         "--contract", str(SAMPLE_CONTRACT), "--output", str(out), "--runner", runner, "--workers", "2", "--codec", "h264-fast"],
        env=env, cwd=REPO, capture_output=True, text=True, check=False, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    os.environ["PREFECT_API_URL"] = api_url
    try:
        with temporary_settings({PREFECT_API_URL: api_url}):
            states, task_names, artifacts = asyncio.run(_inspect(api_url))
    finally:
        os.environ.pop("PREFECT_API_URL", None)
    assert states == ["Completed"]
    converts = [n for n in task_names if n.startswith("convert ")]
    # one task run per episode, named and tagged by bag and robot
    assert converts == [
        "convert episode_000 bag:episode_000 bagport episode robot:bagport_sample_arm",
        "convert episode_001 bag:episode_001 bagport episode robot:bagport_sample_arm",
    ]
    # the reduce's output files, one task run each (data, then each camera's video file)
    writes = [n for n in task_names if n.startswith("write ")]
    assert any(n.startswith("write data/chunk-000/file-000.parquet") for n in writes), task_names
    assert any(n.startswith("write videos/") for n in writes), task_names
    assert set(artifacts) >= {"bagport-qa", "bagport-summary", "bagport-progress"}
    qa_table = str(artifacts["bagport-qa"])
    assert "episode_000" in qa_table
    assert "episode_001" in qa_table
    assert "verdict" in qa_table
    assert "video PSNR min (dB)" in qa_table
    assert "2 episode(s) converted" in str(artifacts["bagport-summary"])
    assert float(str(artifacts["bagport-progress"])) == pytest.approx(100.0)
