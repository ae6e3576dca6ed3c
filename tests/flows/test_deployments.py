"""prefect.yaml's deployments: they parse and point at real flows that take a ConvertConfig (every field in
their parameter schema, round-tripping, placeholders of unset variables refused or unset); ingestion appends
only new bags."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
import yaml
from prefect.exceptions import ParameterTypeError
from prefect.flows import Flow, load_flow_from_entrypoint
from prefect.utilities.callables import parameter_schema
from prefect.utilities.schema_tools import validate
from prefect.utilities.templating import apply_values

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.dataset.validate import validate_dataset
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import build_parser
from flows.cli_config import convert_config, load_encoder
from flows.deployments import DeploymentConfig, ParameterNotSetError, ingest, reconvert
from flows.runners import prefect_api
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT, SMALL_CAMERAS

ENV = {
    "BAGPORT_BAGS_GLOB": "s3://fleet/bags/*",
    "BAGPORT_CONTRACT": "configs/contracts/sample_robot.yaml",
    "BAGPORT_OUTPUT": "s3://fleet/datasets/fleet",
    "BAGPORT_MANIFEST": "s3://fleet/manifest.yaml",
    "BAGPORT_RECONVERT_OUTPUT": "s3://fleet/datasets/reconverted",
}
"""The variables prefect.yaml's placeholders need (the optional ones unset)."""


def _deployed(monkeypatch: pytest.MonkeyPatch, **env: str) -> dict[str, dict[str, Any]]:
    """prefect.yaml's deployments by name, templated as `prefect deploy` does with this environment."""
    for name in (*ENV, "BAGPORT_STAGING", "BAGPORT_DASK_ADDRESS", "BAGPORT_RAY_ADDRESS"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    spec: dict[str, Any] = yaml.safe_load((REPO / "prefect.yaml").read_text())
    # as prefect/cli/deploy/_core.py: environment placeholders filled (unset ones kept), then the ones left
    # emptied (its second pass, with the steps' outputs)
    filled = apply_values(list(spec["deployments"]), dict(os.environ), remove_notset=False)
    assert isinstance(filled, list)
    templated = apply_values(filled, {}, warn_on_notset=False)
    assert isinstance(templated, list)
    return {d["name"]: d for d in templated}


def _flow(deployment: dict[str, Any]) -> Flow[..., Any]:
    """The deployment's flow (as imported here: the entrypoint's own copy has its own error classes)."""
    loaded: Flow[..., Any] = load_flow_from_entrypoint(str(REPO / deployment["entrypoint"]))
    flow: Flow[..., Any] = {"ingest": ingest, "reconvert": reconvert}[deployment["entrypoint"].rsplit(":")[1]]
    assert parameter_schema(loaded) == parameter_schema(flow)
    return flow


def _run_config(deployment: dict[str, Any], parameters: dict[str, Any] | None = None) -> ConvertConfig:
    """The config a run of ``deployment`` gets: its parameters checked against the flow's schema as the
    server checks them, then validated as the engine does."""
    flow = _flow(deployment)
    given = deployment["parameters"] | (parameters or {})  # the server's merge: a run's config replaces
    assert validate(given, parameter_schema(flow).model_dump_for_openapi(), raise_on_error=True) == []
    config: DeploymentConfig = flow.validate_parameters(given)["config"]
    return config.convert_config()


def test_prefect_yaml_deployments_point_at_flows_with_valid_parameters(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    deployments = _deployed(monkeypatch, **ENV)
    assert set(deployments) == {"fleet-ingestion", "reconvert"}
    assert deployments["fleet-ingestion"]["schedules"][0]["cron"] == "0 * * * *"
    # one run at a time; a run due while the previous one works is cancelled, not queued
    assert deployments["fleet-ingestion"]["concurrency_limit"] == {
        "limit": 1,
        "collision_strategy": "CANCEL_NEW",
    }
    ingestion = _run_config(deployments["fleet-ingestion"])
    assert (ingestion.bags_glob, ingestion.output, ingestion.staging) == (
        "s3://fleet/bags/*",
        "s3://fleet/datasets/fleet",
        None,  # BAGPORT_STAGING unset: the placeholder counts as unset
    )
    assert (ingestion.runner, ingestion.dask_address, ingestion.ray_address) == ("process", None, None)
    assert ingestion.encoder == load_encoder("h264-fast")  # `codec: h264-fast`, as in a run.yaml
    again = _run_config(deployments["reconvert"])
    assert (again.manifest, again.output, again.keep_staging) == (
        "s3://fleet/manifest.yaml",
        "s3://fleet/datasets/reconverted",
        True,
    )


def test_the_parameter_schema_holds_every_convert_config_field() -> None:
    for flow in (ingest, reconvert):
        schema = parameter_schema(flow).model_dump_for_openapi()
        assert list(schema["properties"]) == ["config"]
        fields = schema["definitions"]["DeploymentConfig"]["properties"]
        assert set(ConvertConfig.model_fields) | {"codec"} == set(fields)
        assert fields["runner"]["enum"] == ["process", "thread", "dask", "ray"]


def test_a_convert_config_round_trips_as_deployment_parameters(monkeypatch: pytest.MonkeyPatch) -> None:
    config = ConvertConfig(
        manifest="s3://fleet/manifest.yaml",
        contract="s3://fleet/contracts/robot.yaml",
        output="s3://fleet/datasets/robot",
        runner="ray",
        ray_address="ray://head:10001",
        workers=8,
        encoder=load_encoder("archival"),
        formats=("lerobot", "hdf5"),
        hdf5_jpeg_quality=80,
        on_qa_fail="keep",
        keep_failed=True,
        fail_fast=True,
        chunks_size=10,
        msg_path="msgs",
    )
    reconvert_spec = _deployed(monkeypatch, **ENV)["reconvert"]
    assert _run_config(reconvert_spec, {"config": config.model_dump(mode="json")}) == config
    assert reconvert.validate_parameters({"config": config})["config"].convert_config() == config


def test_a_run_yaml_is_a_deployment_config() -> None:
    """The same keys: configs/run.yaml as a deployment's ``config`` gives the run `--config` gives."""
    run_yaml = yaml.safe_load((REPO / "configs/run.yaml").read_text())
    parser = build_parser()
    args = parser.parse_args(["convert", "--config", str(REPO / "configs/run.yaml")])
    from_cli = convert_config(args, vars(parser.parse_args(["convert"])))
    assert reconvert.validate_parameters({"config": run_yaml})["config"].convert_config() == from_cli


def test_a_command_line_only_option_in_a_deployment_config_is_named() -> None:
    """``push_to_hub`` (or ``quiet``...) is about the CLI command, not the run: named, not pydantic's bare
    'Extra inputs are not permitted'."""
    run_yaml = yaml.safe_load((REPO / "configs/run.yaml").read_text())
    with pytest.raises(ParameterTypeError) as caught:
        reconvert.validate_parameters({"config": {**run_yaml, "push_to_hub": True, "quiet": True}})
    said = str(caught.value)
    assert "push_to_hub and quiet are options of the `bagport convert` command, not of a run" in said, said
    assert "`bagport push OUT --repo-id ORG/NAME`" in said
    assert "Extra inputs are not permitted" not in said


def test_a_filled_address_picks_its_runner(monkeypatch: pytest.MonkeyPatch) -> None:
    ray = _deployed(monkeypatch, **ENV, BAGPORT_RAY_ADDRESS="ray://head:10001")["fleet-ingestion"]
    assert (_run_config(ray).runner, _run_config(ray).ray_address) == ("ray", "ray://head:10001")
    dask = _deployed(monkeypatch, **ENV, BAGPORT_DASK_ADDRESS="tcp://scheduler:8786")["reconvert"]
    assert (_run_config(dask).runner, _run_config(dask).dask_address) == ("dask", "tcp://scheduler:8786")
    pinned = {"config": dask["parameters"]["config"] | {"runner": "ray"}}  # an explicit runner is kept
    with pytest.raises(ParameterTypeError, match="dask_address 'tcp://scheduler:8786' is only used with"):
        _run_config(dask, pinned)


def test_deployment_parameters_are_placeholders_a_run_refuses_until_set(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Finding 5 of issue 16: prefect.yaml pointed at example S3 and /data paths that went live on deploy."""
    raw: dict[str, Any] = yaml.safe_load((REPO / "prefect.yaml").read_text())
    raw_ingestion = next(d for d in raw["deployments"] if d["name"] == "fleet-ingestion")
    assert raw_ingestion["parameters"]["config"]["output"] == "{{ $BAGPORT_OUTPUT }}"
    with pytest.raises(
        ParameterNotSetError,
        match=r"'config.contract' is not set: it still holds .*export BAGPORT_CONTRACT=\.\.\.",
    ):
        ingest(config=raw_ingestion["parameters"]["config"])  # not templated: the placeholders themselves
    unset = ("BAGPORT_OUTPUT", "BAGPORT_MANIFEST")
    deployments = _deployed(monkeypatch, **{k: v for k, v in ENV.items() if k not in unset})
    ingestion = deployments["fleet-ingestion"]
    assert ingestion["parameters"]["config"]["output"] == ""  # what `prefect deploy` leaves
    with pytest.raises(
        ParameterNotSetError, match=r"'config.output' is not set: it is empty.*prefect deploy --all"
    ):
        _run_config(ingestion)
    with pytest.raises(ParameterNotSetError, match=r"'config.manifest' is not set.*--param config="):
        _run_config(deployments["reconvert"])


@pytest.mark.slow
def test_scheduled_ingestion_appends_only_new_bags(tmp_path: Path) -> None:
    bags = tmp_path / "fleet"
    for name in ("day1_a", "day1_b"):
        write_episode_bag(bags / name, "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS, task=name))
    out = tmp_path / "dataset"
    config = DeploymentConfig(
        bags_glob=str(bags / "day*"),
        contract=str(SAMPLE_CONTRACT),
        output=str(out),
        encoder=FAST_CODEC,
        workers=1,
    )
    with prefect_api():
        first = ingest(config)
        assert isinstance(first, DatasetReport)  # not a state: nothing excluded
        assert (first.episodes, first.tasks) == (2, ("day1_a", "day1_b"))
        write_episode_bag(
            bags / "day2_a", "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS, task="day2_a")
        )
        second = ingest(config)
        third = ingest(config)  # nothing new: nothing converted
        assert isinstance(second, DatasetReport) and isinstance(third, DatasetReport)
        assert (second.episodes, third.episodes) == (3, 3)
    runs = sorted(p.name for p in (out / "meta/provenance").glob("run*.json"))
    assert runs == ["run-001.json", "run.json"]
    record = json.loads((out / "meta/provenance/run-001.json").read_text())
    assert [Path(u).name for u in record["manifest"]["converted_now"]] == ["day2_a"]


@pytest.mark.slow
@pytest.mark.xdist_group("ray")  # one local Ray instance at a time under xdist
def test_a_deployment_runs_on_ray(tmp_path: Path) -> None:
    """The reconvert flow given a config as a deployment's JSON parameter (runner ray, no address: a local
    instance of `workers` CPUs), in a process of its own as a worker runs it."""
    bags = tmp_path / "bags"
    for seed in (1, 2):
        write_episode_bag(bags / f"ep{seed}", "mcap", EpisodeSpec(duration_s=0.5, seed=seed))
    out = tmp_path / "dataset"
    config = {
        "bags_glob": str(bags / "ep*"),
        "contract": str(SAMPLE_CONTRACT),
        "output": str(out),
        "runner": "ray",
        "ray_address": "",  # what `prefect deploy` leaves of an unset BAGPORT_RAY_ADDRESS
        "workers": 2,
        "codec": "h264-fast",
    }
    script = (
        "import json, sys\n"
        "from flows.deployments import reconvert\n"
        "from flows.runners import prefect_api\n"
        "with prefect_api():\n"
        "    reconvert(config=json.loads(sys.argv[1]))\n"
    )
    ray_tmp = tempfile.mkdtemp(prefix="bagport-ray-")  # short: Unix socket paths are limited
    # Prefect's default level, as a worker runs it (the tests' is WARNING): Ray's INFO lines follow it
    env = {**os.environ, "RAY_TMPDIR": ray_tmp, "BAGPORT_DEBUG": "0", "PREFECT_LOGGING_LEVEL": "INFO"}
    try:
        done = subprocess.run(
            [sys.executable, "-c", script, json.dumps(config)],
            cwd=REPO, env=env, capture_output=True, text=True, timeout=300, check=False,
        )  # fmt: skip
    finally:
        shutil.rmtree(ray_tmp, ignore_errors=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Started a local Ray instance" in done.stdout + done.stderr
    assert validate_dataset(out, repo_id="test/ray-deployment").episodes == 2
