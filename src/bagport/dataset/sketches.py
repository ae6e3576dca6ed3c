"""The dataset's merged quantile sketches: ``meta/provenance/quantile_sketches.json``.

```
{"k": 800, "values": {feature: [base64 KLL sketch per dimension]},
           "steps":  {feature: [base64 KLL sketch of |frame-to-frame step| per dimension]}}
```
``values`` give the dataset quantiles in ``stats.json`` (see :mod:`bagport.stats.sketch` for the
bound); ``steps`` give the fleet's own distribution of joint steps, against which the jump check
(:mod:`bagport.qa.jumps`) judges new episodes. LeRobot never reads this file; ``info.json`` is
left alone. An append reads this file, never an old data file.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.columns import column_matrix
from bagport.dataset.layout import SKETCHES_PATH
from bagport.stats import SKETCH_K, VectorSketch

__all__ = ["DatasetSketches", "read_sketches", "sketches_from_data_files"]


@dataclass(slots=True)
class DatasetSketches:
    values: dict[str, VectorSketch] = field(default_factory=dict)
    steps: dict[str, VectorSketch] = field(default_factory=dict)

    def merge(self, other: DatasetSketches) -> None:
        for mine, theirs in ((self.values, other.values), (self.steps, other.steps)):
            for key, sketch in theirs.items():
                if key in mine:
                    mine[key].merge(sketch)
                else:
                    mine[key] = VectorSketch.merged([sketch]) or sketch

    def to_json(self) -> dict[str, object]:
        return {
            "k": SKETCH_K,
            "values": {key: s.to_json() for key, s in self.values.items()},
            "steps": {key: s.to_json() for key, s in self.steps.items()},
        }

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> DatasetSketches:
        return cls(
            {key: VectorSketch.from_json(v) for key, v in raw.get("values", {}).items()},
            {key: VectorSketch.from_json(v) for key, v in raw.get("steps", {}).items()},
        )

    def __reduce__(self) -> tuple[Any, tuple[dict[str, Any]]]:
        """Pickled as its JSON form (the sketches themselves are C++ objects): a write session carries the
        dataset's sketches to the commit, in another process."""
        return (DatasetSketches.from_json, (self.to_json(),))

    def write(self, root: Path) -> None:
        path = root / SKETCHES_PATH
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json()))


def read_sketches(fs: AbstractFileSystem, root: str) -> DatasetSketches | None:
    """The dataset's stored sketches, or ``None`` for a dataset written before they were kept."""
    path = f"{root}/{SKETCHES_PATH}"
    if not fs.isfile(path):
        return None
    with fs.open(path, "r", encoding="utf-8") as handle:
        raw = json.load(handle)
    return DatasetSketches.from_json(raw)


def sketches_from_data_files(data_files: Sequence[str], keys: Sequence[str]) -> DatasetSketches:
    """Sketch the values of ``keys`` from a dataset's data files: once, for a dataset written before
    sketches were kept (its next append stores them, and no later append reads a data file)."""
    out = DatasetSketches()
    for uri in data_files:
        fs, path = url_to_fs(uri)
        with fs.open(path, "rb") as handle:
            for batch in pq.ParquetFile(handle).iter_batches(
                batch_size=65_536, columns=[*keys, "episode_index"]
            ):
                episodes = batch.column("episode_index").to_numpy()
                for key in keys:
                    values = column_matrix(batch.column(key))
                    sketch = out.values.setdefault(key, VectorSketch(values.shape[1]))
                    sketch.update(values)
                    steps = np.abs(np.diff(values, axis=0))[np.diff(episodes) == 0]
                    out.steps.setdefault(key, VectorSketch(values.shape[1])).update(steps)
    return out
