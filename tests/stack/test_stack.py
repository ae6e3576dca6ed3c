"""The stack as users run it: ``scripts/stack.sh up``, ``prefect deploy --all``, the schedule fires.

PostgreSQL-backed Prefect server, a process worker, moto's S3 endpoint and a Dask cluster, all native
processes started by the script; the fleet-ingestion deployment runs because its schedule (set to a
few seconds here) fires; reconvert is started through the API; everything is read back through the
API, then in Chromium on the Prefect UI. Runtime: about 4-6 min on 2 shared cores (stack start ~50 s).
"""

from __future__ import annotations

import asyncio
import json
import os
import shlex
import subprocess
import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path
from typing import Any

import psutil
import pytest
from playwright.sync_api import Page, sync_playwright
from prefect.client.orchestration import PrefectClient, get_client
from prefect.client.schemas.actions import DeploymentScheduleCreate
from prefect.client.schemas.filters import (
    ArtifactFilter,
    ArtifactFilterFlowRunId,
    DeploymentFilter,
    DeploymentFilterId,
    FlowRunFilter,
    FlowRunFilterId,
    FlowRunFilterParentFlowRunId,
    FlowRunFilterState,
    FlowRunFilterStateType,
)
from prefect.client.schemas.objects import Artifact, FlowRun, StateType
from prefect.client.schemas.schedules import CronSchedule, IntervalSchedule
from prefect.client.schemas.sorting import FlowRunSort
from prefect.settings import PREFECT_API_URL, temporary_settings
from s3fs import S3FileSystem

from bagport.dataset.validate import validate_dataset
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import REPO, SAMPLE_CONTRACT, SMALL_CAMERAS

pytestmark = pytest.mark.slow

CHROMIUM = "/usr/bin/chromium"  # Debian's (scripts/setup_browser.sh): browsers cannot be downloaded here


def _read_env(path: Path) -> dict[str, str]:
    env: dict[str, str] = {}
    for line in path.read_text().splitlines():
        if line.startswith("export "):
            key, _, value = line.removeprefix("export ").partition("=")
            env[key] = shlex.split(value)[0] if value else ""
    return env


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    root = tmp_path_factory.mktemp("stack")
    env = {
        **os.environ,
        "BAGPORT_STACK_DIR": str(root),
        "PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS": "2",  # the schedule fires within seconds
    }
    up = subprocess.run(
        ["bash", "scripts/stack.sh", "up"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    pids = [int(line.split()[1]) for line in (root / "pids").read_text().splitlines()]
    try:
        assert up.returncode == 0, up.stderr
        yield {**os.environ, **_read_env(root / "stack.env")}
    finally:
        down = subprocess.run(
            ["bash", "scripts/stack.sh", "down"],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert down.returncode == 0, down.stderr
        left = [
            p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
        ]
        assert not left, f"stack processes left running: {left}"


def _upload_bag(fs: S3FileSystem, tmp: Path, name: str) -> None:
    local = tmp / "bags" / name
    write_episode_bag(local, "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS, task=f"task {name}"))
    fs.put(str(local), f"fleet/bags/{name}", recursive=True)


async def _finished_runs(client: PrefectClient, deployment_id: Any) -> list[FlowRun]:
    """The deployment's runs that ended Completed (with or without exclusions), Failed or Crashed."""
    final = [StateType.COMPLETED, StateType.FAILED, StateType.CRASHED]
    return await client.read_flow_runs(
        deployment_filter=DeploymentFilter(id=DeploymentFilterId(any_=[deployment_id])),
        flow_run_filter=FlowRunFilter(state=FlowRunFilterState(type=FlowRunFilterStateType(any_=final))),
        sort=FlowRunSort.EXPECTED_START_TIME_ASC,
    )


async def _wait_run(
    client: PrefectClient, deployment_id: Any, seen: set[Any], timeout_s: float = 240
) -> FlowRun:
    """The next run of the deployment not in ``seen`` that finished (a scheduled run due while the
    previous one works is cancelled, collision strategy CANCEL_NEW: those are not waited for)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for run in await _finished_runs(client, deployment_id):
            if run.id not in seen:
                seen.add(run.id)
                return run
        await asyncio.sleep(1)
    raise AssertionError(f"no run of deployment {deployment_id} finished within {timeout_s:g} s")


async def _subflows(client: PrefectClient, run: FlowRun) -> list[Any]:
    children = await client.read_flow_runs(
        flow_run_filter=FlowRunFilter(parent_flow_run_id=FlowRunFilterParentFlowRunId(any_=[run.id]))
    )
    return [child.id for child in children]


async def _artifacts(client: PrefectClient, run: FlowRun) -> list[Artifact]:
    return await client.read_artifacts(
        artifact_filter=ArtifactFilter(flow_run_id=ArtifactFilterFlowRunId(any_=[run.id]))
    )


async def _task_runs(client: PrefectClient, run: FlowRun) -> list[str]:
    """``<name> <tags>`` of the convert tasks of the run's conversion subflow."""
    subflows = await _subflows(client, run)
    tasks = await client.read_task_runs(flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=subflows)))
    return sorted(
        f"{t.name} {' '.join(sorted(x for x in t.tags if x.startswith('bag:')))} {t.state_name}"
        for t in tasks
        if t.name.startswith("convert ")
    )


async def _scenario(env: dict[str, str], tmp: Path) -> dict[str, Any]:
    fs = S3FileSystem()
    story: dict[str, Any] = {}
    async with get_client() as client:
        ingestion = await client.read_deployment_by_name("bagport-ingest/fleet-ingestion")
        reconvert = await client.read_deployment_by_name("bagport-reconvert/reconvert")
        story["cron"] = [getattr(s.schedule, "cron", None) for s in ingestion.schedules]
        settings = (await client.request("GET", "/admin/settings")).json()
        story["vacuum"] = sorted(settings["server"]["services"]["db_vacuum"]["enabled"])
        # the test's schedule: every 5 s instead of hourly
        for schedule in ingestion.schedules:
            await client.delete_deployment_schedule(ingestion.id, schedule.id)
        every_5_s = DeploymentScheduleCreate(schedule=IntervalSchedule(interval=timedelta(seconds=5)))
        await client.create_deployment_schedules(ingestion.id, [every_5_s])
        seen: set[Any] = set()
        first = await _wait_run(client, ingestion.id, seen)
        story["first"] = (first.name, first.state_name, first.work_pool_name)
        story["first_tasks"] = await _task_runs(client, first)
        story["first_artifacts"] = {str(a.key): str(a.data) for a in await _artifacts(client, first) if a.key}
        _upload_bag(fs, tmp, "day2_a")
        second = await _wait_run(client, ingestion.id, seen)
        while "+0" in str(second.name):  # a run that started before the upload finished
            second = await _wait_run(client, ingestion.id, seen)
        story["second"] = (second.name, second.state_name)
        fs.pipe("fleet/bags/broken.mcap", b"this is not an MCAP file")
        third = await _wait_run(client, ingestion.id, seen)
        while "excluded" not in str(third.name) and "+0" in str(third.name):
            third = await _wait_run(client, ingestion.id, seen)
        story["third"] = (third.name, third.state_name)
        story["third_tasks"] = await _task_runs(client, third)
        fourth = await _wait_run(client, ingestion.id, seen)
        story["fourth"] = (fourth.name, fourth.state_name)
        # back to prefect.yaml's hourly schedule: the deployment page lists its upcoming runs
        for schedule in await client.read_deployment_schedules(ingestion.id):
            await client.delete_deployment_schedule(ingestion.id, schedule.id)
        hourly = DeploymentScheduleCreate(schedule=CronSchedule(cron="0 * * * *", timezone="UTC"))
        await client.create_deployment_schedules(ingestion.id, [hourly])
        story["ui"] = {
            "deployment": str(ingestion.id),
            "first_subflow": str((await _subflows(client, first))[0]),
            "third_subflow": str((await _subflows(client, third))[0]),
            "third_qa": str(next(a.id for a in await _artifacts(client, third) if a.key == "bagport-qa")),
        }
        # reconvert through the API, twice: the second with a changed contract reuses the camera clips
        changed = SAMPLE_CONTRACT.read_text().replace("position.j5, position.j6]", "position.j5]", 1)
        fs.pipe("fleet/contracts/changed.yaml", changed.encode())
        fs.put(str(SAMPLE_CONTRACT), "fleet/contracts/sample.yaml")
        bags = sorted(p.rsplit("/", 1)[-1] for p in fs.ls("fleet/bags") if not p.endswith(".mcap"))
        fs.pipe(
            "fleet/manifest.yaml",
            ("bags:\n" + "".join(f"  - uri: s3://fleet/bags/{b}\n" for b in bags)).encode(),
        )
        reconverts: set[Any] = set()
        for contract, output in (("sample", "re1"), ("changed", "re2")):
            run = await client.create_flow_run_from_deployment(
                reconvert.id,
                parameters={  # a run's config replaces the deployment's: start from it
                    "config": reconvert.parameters["config"]
                    | {
                        "manifest": "s3://fleet/manifest.yaml",
                        "contract": f"s3://fleet/contracts/{contract}.yaml",
                        "output": f"s3://fleet/datasets/{output}",
                        "staging": "s3://fleet/staging/reconvert",
                        "keep_staging": True,
                    }
                },
            )
            done = await _wait_run(client, reconvert.id, reconverts, timeout_s=240)
            assert done.id == run.id
            story[output] = (done.name, done.state_name)
    return story


def _run_order(path: str) -> tuple[bool, str]:
    """``run.json`` (the first run), then ``run-001.json``, ``run-002.json``..."""
    return not path.endswith("/run.json"), path


def _wait_for_text(page: Page, url: str, expected: list[str], shot: Path, timeout_s: float = 60) -> str:
    """Open ``url`` and wait until the page's text holds every expected string; screenshot it."""
    if url:
        page.goto(url)
    deadline = time.monotonic() + timeout_s
    text = ""
    while time.monotonic() < deadline:
        text = page.inner_text("body")
        if all(item in text for item in expected):
            break
        time.sleep(0.5)
    page.screenshot(path=str(shot), full_page=True)
    missing = [item for item in expected if item not in text]
    assert not missing, f"{url or page.url}: {missing} not on the page (screenshot {shot}):\n{text[:3000]}"
    return text


def _check_ui(ui_url: str, ids: dict[str, str], shots: Path) -> None:
    """Chromium (Debian's, through Playwright) on the Prefect UI, as a person looks at the runs."""
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1600, "height": 1200})
            _wait_for_text(
                page, f"{ui_url}/runs", ["Completed with exclusions", "1 excluded"], shots / "runs.png"
            )
            _wait_for_text(
                page, f"{ui_url}/runs/flow-run/{ids['first_subflow']}", ["Task Runs"], shots / "a.png"
            )
            page.get_by_text("Task Runs", exact=True).first.click()
            _wait_for_text(
                page,
                "",
                ["convert day1_a", "bag:day1_a", "convert day1_b", "bag:day1_b"],
                shots / "tasks.png",
            )
            _wait_for_text(
                page, f"{ui_url}/runs/flow-run/{ids['third_subflow']}", ["Task Runs"], shots / "b.png"
            )
            page.get_by_text("Task Runs", exact=True).first.click()
            _wait_for_text(page, "", ["convert broken.mcap", "Failed"], shots / "failed-task.png")
            _wait_for_text(
                page,
                f"{ui_url}/artifacts/artifact/{ids['third_qa']}",
                ["broken.mcap", "excluded", "conversion failed", "is not a ROS bag"],
                shots / "qa-artifact.png",
            )
            _wait_for_text(
                page,
                f"{ui_url}/deployments/deployment/{ids['deployment']}",
                ["fleet-ingestion", "Upcoming", "Scheduled for"],
                shots / "deployment.png",
            )
        finally:
            browser.close()


def test_the_stack_runs_scheduled_ingestion_and_reconvert(
    stack: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for key, value in stack.items():
        if key.startswith(("AWS_", "PREFECT_API")):
            monkeypatch.setenv(key, value)  # for this test only: the stack is gone after it
    S3FileSystem.clear_instance_cache()
    fs = S3FileSystem()
    for name in ("day1_a", "day1_b"):
        _upload_bag(fs, tmp_path, name)
    deploy_env = {
        **stack,
        "BAGPORT_BAGS_GLOB": "s3://fleet/bags/*",
        "BAGPORT_CONTRACT": "configs/contracts/sample_robot.yaml",
        "BAGPORT_OUTPUT": "s3://fleet/datasets/fleet",
        "BAGPORT_STAGING": "s3://fleet/staging/fleet",
        "BAGPORT_MANIFEST": "s3://fleet/manifest.yaml",
        "BAGPORT_RECONVERT_OUTPUT": "s3://fleet/datasets/reconverted",
    }
    prefect = str(REPO / ".venv" / "bin" / "prefect")
    deployed = subprocess.run(
        [prefect, "--no-prompt", "deploy", "--all"],
        cwd=REPO, env=deploy_env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert deployed.returncode == 0, deployed.stdout + deployed.stderr
    with temporary_settings({PREFECT_API_URL: stack["PREFECT_API_URL"]}):
        story = asyncio.run(_scenario(stack, tmp_path))
    (tmp_path / "story.json").write_text(json.dumps(story, indent=2, default=str))
    assert story["cron"] == ["0 * * * *"]  # as deployed from prefect.yaml
    assert story["vacuum"] == ["events", "flow_runs"]  # months of hourly runs do not fill the database
    name, state, pool = story["first"]
    assert (state, pool) == ("Completed", "bagport")
    assert name.startswith("ingest ") and name.endswith(": +2 episode(s)")
    assert story["first_tasks"] == [
        "convert day1_a bag:day1_a Completed",
        "convert day1_b bag:day1_b Completed",
    ]
    assert "2 episode(s) converted" in story["first_artifacts"]["bagport-summary"]
    assert story["second"][0].endswith(": +1 episode(s)")
    assert story["third"][1] == "Completed with exclusions"
    assert story["third"][0].endswith(": +0 episode(s), 1 excluded")
    assert [t.split()[1] for t in story["third_tasks"]] == ["broken.mcap"]
    assert story["third_tasks"][0].endswith("Failed")
    assert story["fourth"][0].endswith(": +0 episode(s)")  # the unchanged broken bag is not retried
    assert story["re2"][1] == "Completed"
    records = [
        json.loads(fs.cat(p))
        for p in sorted(fs.glob("fleet/datasets/fleet/meta/provenance/run*.json"), key=_run_order)
    ]
    assert [[Path(u).name for u in r["manifest"]["converted_now"]] for r in records] == [
        ["day1_a", "day1_b"],
        ["day2_a"],
        ["broken.mcap"],
    ]
    reused = json.loads(fs.cat("fleet/datasets/re2/meta/provenance/run.json"))
    assert [sorted(e["reused_clips"]) for e in reused["episodes"]] == [
        ["observation.images.front", "observation.images.wrist"]
    ] * 3
    _check_ui(stack["PREFECT_UI_URL"], story["ui"], tmp_path)
    local = tmp_path / "fleet"
    fs.get("fleet/datasets/fleet", str(local), recursive=True)
    assert validate_dataset(local, repo_id="test/stack", decode_every=5).episodes == 3
