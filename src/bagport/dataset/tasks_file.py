"""``meta/tasks.parquet`` as LeRobot's loader reads it: a pandas frame indexed by ``task``, with each task's
``task_index``, written by pandas (its index goes into the file's pandas metadata).

pandas is imported when the file is read or written, not with this module: the conversion's pool
workers import the dataset modules (through the flow's own module) but never this file, and pandas was
a sixth of their start-up imports (0.2 s of CPU beside the temporary server's boot on 2 cores).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["read_tasks_frame", "write_tasks"]


def write_tasks(path: Path, tasks: Sequence[str]) -> None:
    """``tasks`` in the order of their index."""
    import pandas as pd  # noqa: PLC0415 - see the module docstring

    frame = pd.DataFrame(
        {"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, name="task")
    )
    frame.to_parquet(path)


def read_tasks_frame(
    source: str | Path | IO[bytes], storage_options: Mapping[str, Any] | None = None
) -> pd.DataFrame:
    """The file as LeRobot reads it (``pd.read_parquet``), from a path, a URL or an open file."""
    import pandas as pd  # noqa: PLC0415 - see the module docstring

    return pd.read_parquet(source, storage_options=dict(storage_options) if storage_options else None)
