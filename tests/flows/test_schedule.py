"""A real Prefect server schedules runs of a deployment (the locked SQLAlchemy must not break its scheduler).

With SQLAlchemy 2.1 the scheduler service of Prefect 3.8.8 fails in ``_insert_scheduled_flow_runs``
("Can't evaluate bulk DML statement") and no run is ever scheduled; pyproject pins 2.0.x.
"""

from __future__ import annotations

import asyncio
import time
from datetime import timedelta
from pathlib import Path

import pytest
from prefect.client.orchestration import get_client
from prefect.client.schemas.actions import DeploymentScheduleCreate
from prefect.client.schemas.filters import DeploymentFilter, DeploymentFilterId
from prefect.client.schemas.schedules import IntervalSchedule
from prefect.settings import PREFECT_API_URL, temporary_settings

from tests.prefect_server import prefect_server

pytestmark = pytest.mark.slow


async def _deploy_and_wait(timeout_s: float) -> list[str]:
    async with get_client() as client:
        flow_id = await client.create_flow_from_name("bagport-ingest")
        deployment_id = await client.create_deployment(
            flow_id,
            "fleet-ingestion",
            schedules=[DeploymentScheduleCreate(schedule=IntervalSchedule(interval=timedelta(minutes=5)))],
        )
        deadline = time.monotonic() + timeout_s
        while True:
            runs = await client.read_flow_runs(
                deployment_filter=DeploymentFilter(id=DeploymentFilterId(any_=[deployment_id]))
            )
            if runs or time.monotonic() > deadline:
                return sorted(str(run.state_name) for run in runs)
            await asyncio.sleep(1)


def test_the_server_schedules_runs_of_a_deployment(tmp_path: Path) -> None:
    with prefect_server(tmp_path, PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS="2") as (api_url, _):
        settings = temporary_settings({PREFECT_API_URL: api_url})
        with settings:
            states = asyncio.run(_deploy_and_wait(timeout_s=60))
    log = (tmp_path / "prefect-server.log").read_text(errors="replace")
    assert "Can't evaluate bulk DML" not in log
    # the scheduler fills the next runs (at least min_runs of them) as Scheduled
    assert len(states) >= 3, log[-3000:]
    assert set(states) == {"Scheduled"}
