"""bagport's temporary Prefect server as a library caller gets it (``prefect_api()`` without the CLI):
one server for the whole run, Prefect's own threads included."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from prefect import get_client
from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterName
from prefect.server.api.server import SubprocessASGIServer

from bagport.config import ConvertConfig
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.convert import run_config
from flows.runners import prefect_api
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

BAGS = ("a", "b", "c")


def _task_run_names(flow_run_name: str) -> set[str]:
    # the temporary server's database keeps earlier runs ($PREFECT_HOME/prefect.db): ask for this one
    flow_run = FlowRunFilter(name=FlowRunFilterName(any_=[flow_run_name]))
    with get_client(sync_client=True) as client:
        runs = client.read_task_runs(flow_run_filter=flow_run)
    return {run.name for run in runs if run.state is not None and run.state.is_completed()}


def test_a_library_run_on_the_process_pool_starts_no_other_server(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    started: list[str] = []
    start = SubprocessASGIServer.start

    def record_start(self: SubprocessASGIServer, *args: Any, **kwargs: Any) -> None:
        started.append(threading.current_thread().name)
        start(self, *args, **kwargs)

    monkeypatch.setattr(SubprocessASGIServer, "start", record_start)
    cameras = (  # the sample contract's cameras
        CameraSpec("front", "raw", "bgr8", height=32, width=32),
        CameraSpec("wrist", "jpeg", height=32, width=32),
    )
    for i, name in enumerate(BAGS):
        write_episode_bag(tmp_path / name, "mcap", EpisodeSpec(duration_s=0.5, seed=i, cameras=cameras))
    (tmp_path / "manifest.yaml").write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in BAGS))
    out = tmp_path / "ds"
    config = ConvertConfig(
        manifest=str(tmp_path / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(out),
        encoder=FAST_CODEC, runner="process", workers=2,
    )  # fmt: skip
    expected = {f"convert {name}" for name in BAGS}
    with prefect_api():
        assert run_config(config).episodes == len(BAGS)
        # the task runs, as the UI lists them (their last states may arrive a moment after the flow's end)
        deadline = time.monotonic() + 30
        while not expected <= (names := _task_run_names(f"convert {out}")) and time.monotonic() < deadline:
            time.sleep(0.5)
    # Prefect's forwarder of the workers' events (and its global event loop thread) once read the settings
    # Prefect took from the environment at import, without the API URL: each started a temporary server of
    # its own (about 2 s of a 12 s run here) and the workers' events went there
    assert started == []
    assert expected <= names
