"""The worker image and the compose stack, checked as far as a machine without Docker can."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.helpers import REPO

DOCKER = REPO / "docker"


def test_dockerfile_passes_hadolint() -> None:
    hadolint = Path(sys.executable).with_name("hadolint")
    result = subprocess.run(
        [str(hadolint), str(DOCKER / "Dockerfile")], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_dockerfile_is_pinned_and_runs_as_non_root() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    assert "FROM python:3.12.8-slim-bookworm" in text
    assert "uv==0.13.9" in text
    assert "uv sync --locked --no-dev" in text
    assert "\nUSER 10001\n" in text


def test_compose_stack_has_every_service_wired() -> None:
    spec: dict[str, Any] = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = spec["services"]
    assert set(services) >= {
        "postgres",
        "prefect-server",
        "minio",
        "dask-scheduler",
        "dask-worker",
        "prefect-worker",
    }
    assert (
        "postgresql+asyncpg://"
        in services["prefect-server"]["environment"]["PREFECT_API_DATABASE_CONNECTION_URL"]
    )
    for name in ("dask-worker", "prefect-worker"):
        env = services[name]["environment"]
        assert env["PREFECT_API_URL"] == "http://prefect-server:4200/api"
        assert env["AWS_ENDPOINT_URL"] == "http://minio:9000"
        assert services[name]["image"] == "bagport-worker:latest"
    assert services["dask-worker"]["command"][:3] == ["dask", "worker", "tcp://dask-scheduler:8786"]
    for service in services.values():
        image = service.get("image", "")
        assert ":latest" not in image or image == "bagport-worker:latest", f"unpinned image {image}"


@pytest.mark.slow
def test_image_install_command_works_in_a_fresh_venv_without_torch(tmp_path: Path) -> None:
    """The Dockerfile's `uv sync --locked --no-dev`, into a fresh environment: the worker imports, torch does not."""
    venv = tmp_path / "venv"
    env = {**os.environ, "UV_PROJECT_ENVIRONMENT": str(venv), "UV_PYTHON_DOWNLOADS": "never"}
    for args in (["--no-install-project"], []):
        subprocess.run(
            [str(Path(sys.executable).with_name("uv")), "sync", "--locked", "--no-dev", "--quiet", *args],
            cwd=REPO, env=env, check=True, timeout=900,
        )  # fmt: skip
    probe = (
        "import importlib.util, bagport, flows.convert, tasks.episode, distributed, prefect_dask;"
        "print(importlib.util.find_spec('torch') is None, importlib.util.find_spec('lerobot') is None)"
    )
    out = subprocess.run(
        [str(venv / "bin" / "python"), "-c", probe],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.split() == ["True", "True"]
