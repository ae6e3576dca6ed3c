"""Writers for the per-episode frame table (streamed as frames arrive) and provenance table.

Rows are buffered in small batches and written as they fill, so memory does not
grow with episode length.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq

if TYPE_CHECKING:
    from bagport.episode.assemble import AlignedSource

__all__ = ["FrameTableWriter", "vector_type", "write_provenance"]

_BATCH_ROWS = 1024
Int64Array = npt.NDArray[np.int64]


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
        ("source_publish_ns", pa.int64()),
        ("packet_index", pa.int64()),
    ]
)


def write_provenance(path: Path, sources: Sequence[AlignedSource], ticks_ns: Int64Array) -> None:
    """One row per frame and contract source (frame-major): which message fed it, and its times.

    Built from the per-tick selections with numpy, a block of frames at a time: no Python
    work per frame, and memory bounded by the block whatever the episode length.
    """
    with pq.ParquetWriter(path, PROVENANCE_SCHEMA, compression="zstd") as writer:
        for start in range(0, max(int(ticks_ns.size), 1), _BATCH_ROWS * 16):
            frames = np.arange(start, min(start + _BATCH_ROWS * 16, int(ticks_ns.size)), dtype=np.int64)
            if frames.size == 0:
                break
            parts = [_source_block(source, frames, ticks_ns) for source in sources]
            order = np.argsort(np.concatenate([frames] * len(parts)), kind="stable")
            block = pa.concat_tables(parts).take(order)
            writer.write_table(block)


def _source_block(source: AlignedSource, frames: Int64Array, ticks_ns: Int64Array) -> pa.Table:
    sel = source.selection
    lo = sel.lo[frames]
    valid = lo >= 0
    at = np.maximum(lo, 0)
    header, publish = source.timeline.header_ns, source.timeline.publish_ns
    if sel.hi is not None and sel.weight is not None:
        weight = sel.weight[frames].astype(np.float64)
        blended = weight > 0
        hi = sel.hi[frames]
        next_index = _array(hi, ~(blended & (hi >= 0)))
        weights = _array(weight, ~blended)
    else:
        next_index = pa.nulls(frames.size, pa.int64())
        weights = pa.nulls(frames.size, pa.float64())
    filled = source.filled[frames]
    size = int(frames.size)
    skipped = source.timeline.skipped_packets  # video: the packet a sample is, in the window's stream
    packets = pa.nulls(size, pa.int64()) if skipped is None else _array(lo + skipped, ~valid)
    return pa.Table.from_arrays(
        [
            _array(frames),
            _constant(source.src.key, size),
            _constant(source.src.topic, size),
            _array(ticks_ns[frames]),
            _array(source.timeline.log_ns[at], ~valid),
            _array(header[at], ~valid) if header is not None else pa.nulls(size, pa.int64()),
            _constant(source.stamp_used, size),
            _array(lo, ~valid),
            next_index,
            weights,
            _constant(source.src.fill, size, present=filled),
            _array(publish[at], ~valid) if publish is not None else pa.nulls(size, pa.int64()),
            packets,
        ],
        schema=PROVENANCE_SCHEMA,
    )


def _array(values: npt.NDArray[Any], null: npt.NDArray[np.bool_] | None = None) -> pa.Array[Any]:
    array: pa.Array[Any] = pa.array(values, mask=null)
    return array


def _constant(value: str, size: int, present: npt.NDArray[np.bool_] | None = None) -> pa.Array[Any]:
    """``value`` on every row (or on the ``present`` rows, null elsewhere), dictionary-encoded."""
    indices = np.zeros(size, dtype=np.int32)
    mask = None if present is None else ~present
    array: pa.Array[Any] = pa.DictionaryArray.from_arrays(indices, pa.array([value], pa.string()), mask=mask)
    return array
