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
if worker := os.environ.get("PYTEST_XDIST_WORKER"):  # `make test` runs two workers (pytest-xdist)
    # each its own Prefect home: the temporary server's SQLite database and the profiles, not shared
    os.environ["PREFECT_HOME"] = str(Path(os.environ["PREFECT_HOME"]) / worker)
    # Prefect makes its home without its parents (a warning in a fresh clone, where .prefect is missing)
    Path(os.environ["PREFECT_HOME"]).mkdir(parents=True, exist_ok=True)

# The modules with end-to-end runs first: under xdist, a long module left for the end would run while the
# other worker idles (the bagport/ unit tests, short, fill the gaps at the end).
_DIRECTORY_ORDER = ("stack", "flows", "bench", "docker")


def _module_rank(item: pytest.Item, slow_modules: set[Path]) -> tuple[int, bool]:
    parts = item.path.relative_to(REPO / "tests").parts
    directory = _DIRECTORY_ORDER.index(parts[0]) if parts[0] in _DIRECTORY_ORDER else len(_DIRECTORY_ORDER)
    return directory, item.path not in slow_modules


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Each module's tests form one xdist group (``--dist loadgroup``): one worker runs them all, so its
    module fixtures are built once. A module whose tests share something with another module's names its
    group itself (``pytest.mark.xdist_group``); the modules with slow tests go first."""
    slow_modules = {item.path for item in items if item.get_closest_marker("slow") is not None}
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(str(item.path.relative_to(REPO / "tests"))))
    items.sort(key=lambda item: _module_rank(item, slow_modules))


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
