"""What the forkserver imports before it forks the conversion's workers (``flows/worker_preload.py``)."""

from __future__ import annotations

from pathlib import Path

from tests.helpers import python_output

_PROBE = (
    "import sys, flows.worker_preload; "
    "print(*(name in sys.modules for name in ('flows.convert', 'tasks.episode', 'prefect.task_engine', 'pandas')))"
)


def test_the_workers_get_the_flow_and_its_tasks_but_not_pandas(tmp_path: Path) -> None:
    """pandas only reads and writes ``meta/tasks.parquet`` (``bagport.dataset.tasks_file``), which no worker
    does: left out, it is 0.2 s less of the forkserver's imports beside the temporary server's boot."""
    assert python_output(_PROBE, tmp_path / "home") == ["True", "True", "True", "False"]
