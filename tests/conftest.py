"""Test-wide environment: Prefect and Hugging Face state inside the work tree, offline."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REALBAGS = REPO.parent / "shared" / "realbags"

os.environ.setdefault("PREFECT_HOME", str(REPO / ".prefect"))
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("HF_HOME", str(REPO / ".prefect" / "hf"))
os.environ["HF_HUB_OFFLINE"] = "1"


@pytest.fixture(scope="module")
def s3_env() -> Iterator[dict[str, str]]:
    """A real S3-compatible HTTP endpoint on loopback (moto's server), and the standard AWS variables
    pointing at it (also in ``os.environ`` while the module's tests run)."""
    from tests.s3 import moto_s3  # noqa: PLC0415 - moto only for the S3 tests

    with moto_s3() as env:
        yield env


_CLI_KEYS = ("PREFECT_LOGGING_LEVEL", "PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL")
_SESSION_ENV = {key: os.environ.get(key) for key in _CLI_KEYS}


@pytest.fixture(autouse=True)
def _cli_environment() -> Iterator[None]:
    """``bagport``'s ``main()`` sets Prefect's logging variables in ``os.environ`` (it must: before Prefect is
    imported, and for the processes it starts); whatever called it in-process before (a test, a module
    fixture) must not pass them on to this test's subprocesses and worker processes."""
    for key, value in _SESSION_ENV.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    yield
