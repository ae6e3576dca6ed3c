"""The sinks of pass 2: everything that consumes :func:`~bagport.episode.assemble.iter_frames`.

:class:`EpisodeSinks` takes every frame of an episode: each camera's image goes to its
:class:`CameraSink` (encoder, pixel stats, fidelity recorder, QA image checks), the vectors to the
QA value monitor and the :class:`FrameTableWriter` (``frames.parquet``). :func:`write_provenance`
writes the per-frame provenance table from the alignment alone.

Rows are buffered in small batches and written as they fill, so memory does not grow with episode
length.

A colour camera becomes a colour video (the run's codec). A depth camera (``16UC1``, ``32FC1``,
``compressedDepth``; its :class:`~bagport.decode.ImageKind` comes with the frame) becomes a LeRobot
depth video: 12-bit codes (:class:`~bagport.video.depth.DepthQuantizer`, over
``image.depth_range_m``) in a lossless HEVC ``gray12le`` clip, marked ``is_depth_map`` with the
quantiser's parameters, so LeRobot's loader returns depth again. Its stats are of that returned
depth, in metres.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq

from bagport.columns import vector_column
from bagport.contract import ContractPlan, FeatureKind
from bagport.contract.plan import SourceSpec
from bagport.decode import ImageKind
from bagport.episode.alignment import AlignedSource
from bagport.episode.assemble import Frame
from bagport.episode.fidelity import EpisodeFidelity
from bagport.errors import DecodeError, FrameShapeError
from bagport.qa import ValueMonitor
from bagport.staging import FRAMES_FILE
from bagport.stats import ImageStatsAccumulator, episode_sketch_fields, stats_to_json, vector_stats
from bagport.video import ClipInfo, EncoderSettings, StreamingEncoder
from bagport.video.depth import DEPTH_ENCODER, DEPTH_QMAX, DepthQuantizer

__all__ = ["CameraSink", "EpisodeSinks", "FrameTableWriter", "vector_type", "write_provenance"]

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
        self._only_batch: dict[str, npt.NDArray[Any]] | None = None
        """The vectors written, while they are one batch (a short episode): stats need no read back."""
        self._only_table: pa.Table | None = None
        """The table written, while it is one batch: the data-file size needs no read back either."""
        self._batches = 0
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
        written: dict[str, npt.NDArray[Any]] = {}
        for key, rows in self._values.items():
            stacked = written[key] = np.stack(rows).astype(self._dtypes[key])
            columns[key] = pa.FixedSizeListArray.from_arrays(pa.array(stacked.ravel()), stacked.shape[1])
        self._batches += 1
        self._only_batch = written if self._batches == 1 else None
        batch = pa.table(columns)
        if self._writer is None or self._schema is None:
            self._schema = batch.schema
            self._writer = pq.ParquetWriter(self._path, batch.schema, compression="snappy")
        batch = batch.cast(self._schema)
        self._only_table = batch if self._batches == 1 else None
        self._writer.write_table(batch)
        self._frame_index, self._task = [], []
        self._values = {key: [] for key in self._dtypes}

    def close(self) -> None:
        self._flush()
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def written_table(self) -> pa.Table | None:
        """The closed table, when it was written in one batch (else ``None``: read it back)."""
        return self._only_table if self._writer is None else None

    def written_vectors(self, keys: Sequence[str]) -> dict[str, npt.NDArray[np.float64]] | None:
        """Each of ``keys`` as the (rows, dims) float64 values the closed table holds, when they were
        written in one batch (else ``None``: read the table back)."""
        if self._writer is not None or self._only_batch is None or not set(keys) <= self._only_batch.keys():
            return None
        return {key: np.asarray(self._only_batch[key], dtype=np.float64) for key in keys}


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


_PREVIEW_SHIFT = 4
"""Depth codes >> 4 give the 8-bit picture the QA image checks look at (0 = invalid or nearest)."""


class CameraSink:
    """Feeds one camera's frames, in order, to its encoder, stats, fidelity recorder and QA."""

    def __init__(
        self,
        path: Path,
        source: SourceSpec,
        first: npt.NDArray[Any],
        kind: ImageKind,
        fps: int,
        settings: EncoderSettings,
        fidelity: EpisodeFidelity,
        monitor: ValueMonitor,
    ) -> None:
        self.key = source.key
        self.kind = kind
        self.quantizer: DepthQuantizer | None = None
        if kind is ImageKind.DEPTH:
            self.quantizer = DepthQuantizer()
            if source.depth_range_m is not None:
                low, high = source.depth_range_m
                self.quantizer = DepthQuantizer(depth_min_m=low, depth_max_m=high)
            settings = DEPTH_ENCODER
        elif source.depth_range_m is not None:
            raise DecodeError(
                f"{self.key}: image.depth_range_m is set but {source.topic} carries colour images",
                fix="remove depth_range_m from this entry (it applies to 16UC1/32FC1/compressedDepth topics).",
            )
        self.encoder = StreamingEncoder(
            path, fps=fps, width=first.shape[1], height=first.shape[0], settings=settings
        )
        self.settings = settings
        self.stats = (
            ImageStatsAccumulator(bins=DEPTH_QMAX + 1, levels=self.quantizer.levels())
            if self.quantizer is not None
            else ImageStatsAccumulator()
        )
        self._fidelity = fidelity
        self._monitor = monitor

    def write(self, frame_index: int, image: npt.NDArray[Any]) -> None:
        if self.quantizer is None:
            pixels, preview = image, image
        else:
            pixels = self.quantizer.codes(image)
            preview = (pixels >> _PREVIEW_SHIFT).astype(np.uint8)
        self.encoder.write(pixels)
        self._fidelity.record(self.key, pixels, self.kind)
        self.stats.update(pixels)
        self._monitor.add_image(frame_index, self.key, preview)

    def close(self) -> ClipInfo:
        return self.encoder.close()

    def video_info(self, clip: ClipInfo, fps: int) -> dict[str, Any]:
        """The feature's ``info`` in ``info.json``, as LeRobot 0.6 writes it."""
        info: dict[str, Any] = {
            "video.height": clip.height,
            "video.width": clip.width,
            "video.codec": clip.codec,
            "video.pix_fmt": clip.pix_fmt,
            "video.fps": fps,
            "video.channels": self.channels,
            "has_audio": False,
            **self.settings.to_info(),
            "is_depth_map": False,
        }
        if self.quantizer is not None:
            info.update(self.quantizer.to_info())
        return info

    @property
    def channels(self) -> int:
        return self.kind.channels


class EpisodeSinks:
    """Every consumer of an episode's frames: its cameras, its frame table and the QA value monitor."""

    def __init__(
        self,
        workdir: Path,
        plan: ContractPlan,
        settings: EncoderSettings,
        frame_tasks: Sequence[str],
        monitor: ValueMonitor,
        fidelity: EpisodeFidelity,
        bag_uri: str,
    ) -> None:
        self.workdir, self.plan, self.settings, self.bag_uri = workdir, plan, settings, bag_uri
        self.frame_tasks, self.monitor, self.fidelity = frame_tasks, monitor, fidelity
        vector_dtypes = {f.key: f.dtype for f in plan.features if f.kind is FeatureKind.VECTOR}
        (workdir / "videos").mkdir(parents=True, exist_ok=True)
        self.frames = FrameTableWriter(workdir / FRAMES_FILE, plan.fps, vector_dtypes)
        self.cameras: dict[str, CameraSink] = {}
        self.widths: dict[str, int] = {}
        self.names: Mapping[str, tuple[str, ...]] = {}
        """Each vector's dimension names (as the last frame knew them)."""
        self._camera_sources = {f.key: f.sources[0] for f in plan.features if f.kind is FeatureKind.VIDEO}

    def add(self, frame: Frame) -> None:
        for key, image in frame.images.items():
            try:
                self._camera(key, image, frame).write(frame.index, image)
            except FrameShapeError as err:  # the camera's, not the staged clip's: say which and where
                source = self._camera_sources[key]
                raise DecodeError(
                    f"camera {key}: {err.what}",
                    uri=self.bag_uri,
                    topic=source.topic,
                    t_ns=frame.tick_ns,
                    fix=err.fix,
                ).at_entry(source.entry_text(self.plan.source_name)) from None
        for key, vec in frame.vectors.items():
            width = self.widths.setdefault(key, vec.shape[0])
            if vec.shape[0] != width:
                raise DecodeError(
                    f"{key!r} has {vec.shape[0]} values at frame {frame.index}, {width} before",
                    t_ns=frame.tick_ns,
                    fix="select a fixed set of dimensions with selector.names.",
                )
        self.names = frame.names
        self.monitor.add_vectors(frame.index, frame.vectors)
        self.frames.add(frame.index, self.frame_tasks[frame.index], frame.vectors)

    def _camera(self, key: str, first: npt.NDArray[Any], frame: Frame) -> CameraSink:
        camera = self.cameras.get(key)
        if camera is None:
            camera = self.cameras[key] = CameraSink(
                self.workdir / "videos" / f"{key}.mp4",
                self._camera_sources[key],
                first,
                frame.kinds[key],
                self.plan.fps,
                self.settings,
                self.fidelity,
                self.monitor,
            )
        return camera

    def close(self) -> dict[str, ClipInfo]:
        """Close every writer; returns video clip infos by key."""
        self.frames.close()
        return {key: camera.close() for key, camera in self.cameras.items()}

    def stats(self, vector_keys: Sequence[str]) -> dict[str, Any]:
        """Per-episode stats partials of the vectors (read back from the closed frame table) and cameras."""
        stats: dict[str, Any] = {}
        for name, values in self._vectors(vector_keys).items():
            stats[name] = {**stats_to_json(vector_stats(values)), **episode_sketch_fields(values)}
        for key, camera in self.cameras.items():
            acc = camera.stats
            stats[key] = {**stats_to_json(acc.result()), "histogram": acc.histogram().tolist()}
        return stats

    def _vectors(self, keys: Sequence[str]) -> dict[str, npt.NDArray[np.float64]]:
        """The vectors of the closed frame table: in hand for a short episode, else read back."""
        in_hand = self.frames.written_vectors(keys)
        if in_hand is not None:
            return in_hand
        table = pq.read_table(self.workdir / FRAMES_FILE, columns=list(keys))
        return {name: vector_column(table, name) for name in table.column_names}
