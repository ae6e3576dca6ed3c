"""Streaming writers for the per-episode frame table and provenance table.

Rows are buffered in small batches and written as they fill, so memory does not
grow with episode length.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq

if TYPE_CHECKING:
    from bagport.episode.assemble import AlignedSource

__all__ = ["FrameTableWriter", "ProvenanceWriter", "vector_type"]

_BATCH_ROWS = 1024


def vector_type(dtype: str, width: int) -> pa.DataType:
    return pa.list_(pa.from_numpy_dtype(np.dtype(dtype)), width)


class FrameTableWriter:
    """``timestamp, frame_index, task, <vector features...>`` rows, in frame order."""

    def __init__(self, path: Path, fps: int, vector_dtypes: dict[str, str]) -> None:
        self._path = path
        self._fps = fps
        self._dtypes = vector_dtypes
        self._writer: pq.ParquetWriter | None = None
        self._schema: pa.Schema | None = None
        self._frame_index: list[int] = []
        self._task: list[str] = []
        self._values: dict[str, list[npt.NDArray[Any]]] = {key: [] for key in vector_dtypes}
        self.frames = 0

    def add(self, frame_index: int, task: str, values: dict[str, npt.NDArray[np.float64]]) -> None:
        self._frame_index.append(frame_index)
        self._task.append(task)
        for key, vec in values.items():
            self._values[key].append(vec)
        self.frames += 1
        if len(self._frame_index) >= _BATCH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if not self._frame_index:
            return
        index = np.asarray(self._frame_index, dtype=np.int64)
        columns: dict[str, pa.Array[Any]] = {
            "timestamp": pa.array((index / self._fps).astype(np.float32)),
            "frame_index": pa.array(index),
            "task": pa.array(self._task, type=pa.string()),
        }
        for key, rows in self._values.items():
            stacked = np.stack(rows).astype(self._dtypes[key])
            columns[key] = pa.FixedSizeListArray.from_arrays(pa.array(stacked.ravel()), stacked.shape[1])
        batch = pa.table(columns)
        if self._writer is None or self._schema is None:
            self._schema = batch.schema
            self._writer = pq.ParquetWriter(self._path, batch.schema, compression="snappy")
        self._writer.write_table(batch.cast(self._schema))
        self._frame_index, self._task = [], []
        self._values = {key: [] for key in self._dtypes}

    def close(self) -> None:
        self._flush()
        if self._writer is not None:
            self._writer.close()
            self._writer = None


PROVENANCE_SCHEMA = pa.schema(
    [
        ("frame_index", pa.int64()),
        ("key", pa.dictionary(pa.int32(), pa.string())),
        ("topic", pa.dictionary(pa.int32(), pa.string())),
        ("tick_ns", pa.int64()),
        ("source_log_ns", pa.int64()),
        ("source_header_ns", pa.int64()),
        ("stamp_used", pa.dictionary(pa.int32(), pa.string())),
        ("message_index", pa.int64()),
        ("message_index_next", pa.int64()),
        ("weight", pa.float64()),
        ("fill", pa.dictionary(pa.int32(), pa.string())),
    ]
)


class ProvenanceWriter:
    """One row per frame and contract source: which message fed it, and its times."""

    def __init__(self, path: Path) -> None:
        self._writer = pq.ParquetWriter(path, PROVENANCE_SCHEMA, compression="zstd")
        self._rows: dict[str, list[Any]] = {name: [] for name in PROVENANCE_SCHEMA.names}

    def add_source(self, frame_index: int, tick_ns: int, source: AlignedSource) -> None:
        """The message(s) behind ``source``'s value at this frame, with both clocks."""
        rows = self._rows
        sel = source.selection
        lo = int(sel.lo[frame_index])
        hi = int(sel.hi[frame_index]) if sel.hi is not None else -1
        weight = float(sel.weight[frame_index]) if sel.weight is not None else None
        header = source.timeline.header_ns
        rows["frame_index"].append(frame_index)
        rows["key"].append(source.src.key)
        rows["topic"].append(source.src.topic)
        rows["tick_ns"].append(tick_ns)
        rows["source_log_ns"].append(int(source.timeline.log_ns[lo]) if lo >= 0 else None)
        rows["source_header_ns"].append(int(header[lo]) if lo >= 0 and header is not None else None)
        rows["stamp_used"].append(source.stamp_used)
        rows["message_index"].append(lo if lo >= 0 else None)
        rows["message_index_next"].append(hi if hi >= 0 and weight else None)
        rows["weight"].append(weight if weight else None)
        rows["fill"].append(source.src.fill if bool(source.filled[frame_index]) else None)
        if len(rows["frame_index"]) >= _BATCH_ROWS * 4:
            self._flush()

    def _flush(self) -> None:
        if not self._rows["frame_index"]:
            return
        self._writer.write_table(pa.table(self._rows, schema=PROVENANCE_SCHEMA))
        self._rows = {name: [] for name in PROVENANCE_SCHEMA.names}

    def close(self) -> None:
        self._flush()
        self._writer.close()
