"""prefect.yaml's deployments: they parse and point at real flows; ingestion appends only new bags."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from prefect.flows import Flow, load_flow_from_entrypoint

from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.deployments import ParameterNotSetError, ingest, reconvert
from flows.runners import prefect_api
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=48, width=64),
    CameraSpec("wrist", "jpeg", height=48, width=64),
)


def test_prefect_yaml_deployments_point_at_flows_with_valid_parameters() -> None:
    spec: dict[str, Any] = yaml.safe_load((REPO / "prefect.yaml").read_text())
    deployments = {d["name"]: d for d in spec["deployments"]}
    assert set(deployments) == {"fleet-ingestion", "reconvert"}
    assert deployments["fleet-ingestion"]["schedules"][0]["cron"] == "0 * * * *"
    # one run at a time; a run due while the previous one works is cancelled, not queued
    assert deployments["fleet-ingestion"]["concurrency_limit"] == {
        "limit": 1,
        "collision_strategy": "CANCEL_NEW",
    }
    for deployment in deployments.values():
        flow: Flow[..., Any] = load_flow_from_entrypoint(str(REPO / deployment["entrypoint"]))
        flow.validate_parameters(deployment["parameters"])  # raises on a missing or unknown parameter


def test_deployment_parameters_are_placeholders_a_run_refuses_until_set() -> None:
    """Finding 5 of issue 16: prefect.yaml pointed at example S3 and /data paths that went live on deploy."""
    spec: dict[str, Any] = yaml.safe_load((REPO / "prefect.yaml").read_text())
    ingestion = next(d for d in spec["deployments"] if d["name"] == "fleet-ingestion")
    assert ingestion["parameters"]["output"] == "{{ $BAGPORT_OUTPUT }}"
    reconvert_spec = next(d for d in spec["deployments"] if d["name"] == "reconvert")
    assert {"staging", "keep_staging"} <= set(reconvert_spec["parameters"])
    with pytest.raises(ParameterNotSetError, match=r"'output' is not set.*export BAGPORT_OUTPUT=\.\.\."):
        ingest.fn(**ingestion["parameters"] | {"bags_glob": "s3://fleet/bags/*", "contract": "c.yaml"})
    with pytest.raises(ParameterNotSetError, match=r"'manifest' is not set.*--param manifest="):
        reconvert.fn(**reconvert_spec["parameters"])


@pytest.mark.slow
def test_scheduled_ingestion_appends_only_new_bags(tmp_path: Path) -> None:
    bags = tmp_path / "fleet"
    for name in ("day1_a", "day1_b"):
        write_episode_bag(bags / name, "mcap", EpisodeSpec(duration_s=1.0, cameras=CAMERAS, task=name))
    out = tmp_path / "dataset"
    params: dict[str, Any] = {
        "bags_glob": str(bags / "day*"),
        "contract": str(SAMPLE_CONTRACT),
        "output": str(out),
        "encoder": FAST_CODEC,
        "workers": 1,
    }
    with prefect_api():
        first = ingest(**params)
        assert (first.episodes, first.tasks) == (2, ("day1_a", "day1_b"))
        write_episode_bag(
            bags / "day2_a", "mcap", EpisodeSpec(duration_s=1.0, cameras=CAMERAS, task="day2_a")
        )
        second = ingest(**params)
        assert second.episodes == 3
        third = ingest(**params)  # nothing new: nothing converted
        assert third.episodes == 3
    runs = sorted(p.name for p in (out / "meta/provenance").glob("run*.json"))
    assert runs == ["run-001.json", "run.json"]
    record = json.loads((out / "meta/provenance/run-001.json").read_text())
    assert [Path(u).name for u in record["manifest"]["converted_now"]] == ["day2_a"]
