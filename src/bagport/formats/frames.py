"""A staged episode read back frame by frame, for the writers of formats other than LeRobot.

Everything streams: vector columns and frame times come in row batches, camera frames are decoded one
at a time from the staged clip (through fsspec, so a staging store on S3 works as a local one).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import av
import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.provenance import episode_provenance
from bagport.errors import DatasetWriteError
from bagport.staging import FRAMES_FILE, PROVENANCE_FILE, EpisodeSummary

__all__ = ["VectorBatch", "episode_record", "iter_tick_batches", "iter_vector_batches", "iter_video_frames"]

BATCH_ROWS = 512


@dataclass(frozen=True, slots=True)
class VectorBatch:
    """Rows ``start .. start + len(timestamp)`` of an episode's frames table."""

    start: int
    timestamp: npt.NDArray[np.float32]
    frame_index: npt.NDArray[np.int64]
    task: list[str]
    values: dict[str, npt.NDArray[Any]]
    """Per vector feature: ``(rows, *shape)`` in the staged dtype."""


def _column(table: pa.RecordBatch, name: str, dtype: str, shape: Sequence[int]) -> npt.NDArray[Any]:
    column = table.column(name)
    if isinstance(column, pa.FixedSizeListArray):
        flat = column.flatten().to_numpy(zero_copy_only=False)
        return np.asarray(flat, dtype=dtype).reshape(len(column), *shape)
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=dtype).reshape(len(column), *shape)


def iter_vector_batches(summary: EpisodeSummary) -> Iterator[VectorBatch]:
    """The episode's timestamps, frame indices, tasks and vector features, in row batches."""
    vectors = [f for f in summary.features if f.video_info is None]
    fs, path = url_to_fs(summary.file(FRAMES_FILE))
    start = 0
    with fs.open(path, "rb") as handle:
        for batch in pq.ParquetFile(handle).iter_batches(batch_size=BATCH_ROWS):
            yield VectorBatch(
                start,
                _column(batch, "timestamp", "float32", ()),
                _column(batch, "frame_index", "int64", ()),
                [str(t) for t in batch.column("task").to_pylist()],
                {f.key: _column(batch, f.key, f.dtype, f.shape) for f in vectors},
            )
            start += batch.num_rows


def iter_tick_batches(summary: EpisodeSummary) -> Iterator[npt.NDArray[np.int64]]:
    """Each frame's grid time in the bag's log time (ns, the original timestamp), in batches, in frame
    order (read from the staged provenance, one row per frame and source)."""
    fs, path = url_to_fs(summary.file(PROVENANCE_FILE))
    last = -1
    with fs.open(path, "rb") as handle:
        for batch in pq.ParquetFile(handle).iter_batches(
            batch_size=BATCH_ROWS * 4, columns=["frame_index", "tick_ns"]
        ):
            frames = batch.column("frame_index").to_numpy()
            if frames.size == 0:
                continue
            ticks = batch.column("tick_ns").to_numpy()
            first = np.ones(frames.size, dtype=bool)
            first[1:] = frames[1:] != frames[:-1]
            first[0] = frames[0] != last
            last = int(frames[-1])
            yield ticks[first].astype(np.int64)


def iter_video_frames(summary: EpisodeSummary, key: str) -> Iterator[npt.NDArray[np.uint8]]:
    """The camera's frames decoded from the staged clip (RGB ``HxWx3`` uint8), one at a time; exactly
    ``summary.frames`` of them or a :class:`DatasetWriteError`."""
    uri = summary.file(summary.videos[key])
    fs, path = url_to_fs(uri)
    count = 0
    try:
        with fs.open(path, "rb") as handle, av.open(handle) as container:
            stream = container.streams.video[0]
            for frame in container.decode(stream):
                count += 1
                if count > summary.frames:
                    break
                yield frame.to_ndarray(format="rgb24")
    except (av.error.FFmpegError, FileNotFoundError) as err:
        raise DatasetWriteError(
            f"staged clip {uri} of {summary.bag_uri} could not be decoded ({err}). Fix: remove the staged "
            f"episode {summary.dir_uri} and convert again."
        ) from err
    if count != summary.frames:
        raise DatasetWriteError(
            f"staged clip {uri} of {summary.bag_uri} holds {count} frames, the episode has {summary.frames}. "
            f"Fix: remove the staged episode {summary.dir_uri} and convert again."
        )


def episode_record(summary: EpisodeSummary, episode_index: int) -> dict[str, Any]:
    """Where the episode came from, as written beside it in every format: its entry in
    ``meta/provenance/run.json``, with the bagport version and contract that staged it."""
    return {
        **episode_provenance(summary, episode_index),
        "bagport_version": summary.bagport_version,
        "contract_sha256": summary.contract_sha256,
    }
