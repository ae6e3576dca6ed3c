"""One HDF5 file per episode in the ALOHA/ACT layout, from the staged episodes (``--format hdf5``).

``episode_<i>.hdf5`` holds ``/observations/qpos`` (``observation.state``), ``/observations/qvel``
(``observation.velocity``), ``/observations/effort`` (``observation.effort``),
``/observations/images/<camera>`` (``observation.images.<camera>``), ``/action`` (``action``); any
other ``observation.<a>.<b>`` goes to ``/observations/<a>/<b>``, ``action.<a>`` to ``/actions/<a>``.
Beside them: ``/timestamp`` (s from the episode start, as LeRobot's), ``/frame_index``, ``/tick_ns``
(each frame's original time in the bag's log time) and ``/task``. Attributes: ``sim`` (False),
``compress``, ``fps``, ``task``, ``tasks``, ``robot_type``, ``episode_index``, ``provenance`` (JSON)
and ``features`` (JSON: each path's contract key, names, dtype, shape).

Images are uint8 ``(T, H, W, 3)`` RGB, decoded from the staged clips; with ``jpeg_quality`` they are
JPEG-compressed like ALOHA's compressed variant: ``(T, padded)`` uint8 rows of JPEG bytes padded with
zeros, the lengths in ``/compress_len`` (cameras x T), encoded as ``cv2.imencode`` encodes, so
``cv2.imdecode(row, 1)`` returns the RGB frame as ALOHA's loaders expect. Every dataset is chunked
and written frame by frame: memory does not grow with the episode's length.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bagport.dataset import DatasetReport
from bagport.errors import BagportError, DatasetWriteError
from bagport.formats.frames import episode_record, iter_tick_batches, iter_vector_batches, iter_video_frames
from bagport.formats.meta import write_format_meta
from bagport.formats.publish import publish_built
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary, StagedFeature

__all__ = ["hdf5_path", "write_hdf5_dataset"]

ALOHA_NAMES = {
    "observation.state": "observations/qpos",
    "observation.velocity": "observations/qvel",
    "observation.effort": "observations/effort",
    "action": "action",
}
VECTOR_CHUNK_ROWS = 256


class Hdf5MissingError(BagportError):
    """``--format hdf5`` without h5py installed."""

    def __init__(self, missing: str) -> None:
        super().__init__(
            f"--format hdf5 needs h5py, which is not installed here ({missing}). Fix: pip install "
            "'bagport[hdf5]' (uv sync --extra hdf5; make setup installs every extra), or leave hdf5 out of --format."
        )


def hdf5_path(key: str) -> str:
    """Where the contract key ``key`` goes in an episode file (see the module docstring)."""
    if key in ALOHA_NAMES:
        return ALOHA_NAMES[key]
    head, _, rest = key.partition(".")
    if head == "observation" and rest:
        return "observations/" + rest.replace(".", "/")
    if head == "action" and rest:
        return "actions/" + rest.replace(".", "/")
    return key.replace(".", "/")


def _layout(features: Sequence[StagedFeature]) -> dict[str, Any]:
    layout = {
        hdf5_path(f.key): {
            "key": f.key,
            "dtype": "uint8" if f.video_info is not None else f.dtype,
            "shape": list(f.shape),
            "names": list(f.names) if f.names is not None else None,
        }
        for f in features
    }
    paths = sorted(layout)
    for path in paths:
        inner = [p for p in paths if p.startswith(path + "/")]
        if inner or path in ("timestamp", "frame_index", "tick_ns", "task", "compress_len"):
            raise DatasetWriteError(
                f"contract key {layout[path]['key']!r} maps to /{path} in HDF5, which "
                f"{'holds ' + inner[0] if inner else 'bagport writes itself'}; nothing was written. "
                "Fix: rename the contract key."
            )
    return layout


def write_hdf5_dataset(
    summaries: Sequence[EpisodeSummary],
    output: str,
    *,
    robot_type: str,
    run_record: dict[str, Any],
    overwrite: bool = False,
    qa: Sequence[QAEntry] = (),
    jpeg_quality: int | None = None,
) -> DatasetReport:
    """Write ``output``/``episode_<i>.hdf5`` for each summary, plus ``meta/`` (published atomically)."""
    try:
        import h5py  # noqa: PLC0415, F401 - an optional extra
    except ImportError as err:
        raise Hdf5MissingError(str(err)) from err
    layout = _layout(summaries[0].features)

    def build(root: Path) -> DatasetReport:
        files = []
        for index, summary in enumerate(summaries):
            name = f"episode_{index}.hdf5"
            _write_episode(root / name, summary, index, robot_type, jpeg_quality, layout)
            files.append(name)
        return write_format_meta(
            root,
            "hdf5",
            summaries,
            files,
            robot_type=robot_type,
            features=layout,
            run_record=run_record,
            qa=qa,
            extra={"layout": "aloha", "compress": jpeg_quality is not None, "jpeg_quality": jpeg_quality},
        )

    return replace(publish_built(output, overwrite=overwrite, build=build), root=output)


def _write_episode(
    path: Path,
    summary: EpisodeSummary,
    index: int,
    robot_type: str,
    jpeg_quality: int | None,
    layout: dict[str, Any],
) -> None:
    import h5py  # noqa: PLC0415 - an optional extra

    frames = summary.frames
    with h5py.File(path, "w") as f:
        f.attrs.update(
            {
                "sim": False,
                "compress": jpeg_quality is not None,
                "fps": summary.fps,
                "task": summary.tasks[0] if summary.tasks else "",
                "tasks": json.dumps(list(summary.tasks)),
                "robot_type": robot_type,
                "episode_index": index,
                "provenance": json.dumps(episode_record(summary, index), default=str),
                "features": json.dumps(layout),
            }
        )
        _write_vectors(f, summary, layout)
        _write_ticks(f, summary)
        cameras = [feature for feature in summary.features if feature.video_info is not None]
        if jpeg_quality is None:
            for camera in cameras:
                _write_raw(f, hdf5_path(camera.key), summary, camera)
            return
        lengths = f.create_dataset("compress_len", (len(cameras), frames), "float32")
        for number, camera in enumerate(cameras):
            _write_jpeg(f, hdf5_path(camera.key), summary, camera, jpeg_quality, lengths, number)


def _chunk_rows(frames: int) -> int:
    return max(1, min(frames, VECTOR_CHUNK_ROWS))


def _write_vectors(f: Any, summary: EpisodeSummary, layout: dict[str, Any]) -> None:
    """``/timestamp``, ``/frame_index``, ``/task`` and every vector feature, batch by batch."""
    import h5py  # noqa: PLC0415 - an optional extra

    frames, rows = summary.frames, _chunk_rows(summary.frames)
    columns = {
        "timestamp": f.create_dataset("timestamp", (frames,), "float32", chunks=(rows,)),
        "frame_index": f.create_dataset("frame_index", (frames,), "int64", chunks=(rows,)),
        "task": f.create_dataset("task", (frames,), h5py.string_dtype(), chunks=(rows,)),
    }
    vectors = {
        feature.key: f.create_dataset(
            hdf5_path(feature.key), (frames, *feature.shape), feature.dtype, chunks=(rows, *feature.shape)
        )
        for feature in summary.features
        if feature.video_info is None
    }
    for key, dataset in vectors.items():
        if layout[hdf5_path(key)]["names"] is not None:
            dataset.attrs["names"] = layout[hdf5_path(key)]["names"]
    for batch in iter_vector_batches(summary):
        end = batch.start + batch.timestamp.size
        columns["timestamp"][batch.start : end] = batch.timestamp
        columns["frame_index"][batch.start : end] = batch.frame_index
        columns["task"][batch.start : end] = batch.task
        for key, dataset in vectors.items():
            dataset[batch.start : end] = batch.values[key]


def _write_ticks(f: Any, summary: EpisodeSummary) -> None:
    """``/tick_ns``: each frame's original time in the bag's log time."""
    ticks = f.create_dataset("tick_ns", (summary.frames,), "int64", chunks=(_chunk_rows(summary.frames),))
    done = 0
    for batch in iter_tick_batches(summary):
        ticks[done : done + batch.size] = batch
        done += batch.size
    if done != summary.frames:
        raise DatasetWriteError(
            f"staged provenance of {summary.bag_uri} times {done} frames, the episode has {summary.frames}. Fix: "
            f"remove the staged episode {summary.dir_uri} and convert again."
        )


def _write_raw(f: Any, target: str, summary: EpisodeSummary, camera: StagedFeature) -> None:
    shape = tuple(camera.shape)
    dataset = f.create_dataset(target, (summary.frames, *shape), "uint8", chunks=(1, *shape))
    for i, frame in enumerate(iter_video_frames(summary, camera.key)):
        dataset[i] = frame


def _write_jpeg(
    f: Any,
    target: str,
    summary: EpisodeSummary,
    camera: StagedFeature,
    quality: int,
    lengths: Any,
    number: int,
) -> None:
    import simplejpeg  # noqa: PLC0415

    row_bytes = max(1024, int(np.prod(camera.shape)) // 16)
    dataset = f.create_dataset(
        target, (summary.frames, 0), "uint8", chunks=(1, row_bytes), maxshape=(summary.frames, None)
    )
    for i, frame in enumerate(iter_video_frames(summary, camera.key)):
        # ALOHA encodes its RGB frames with cv2.imencode, which takes them as BGR: do the same, so that
        # cv2.imdecode gives the RGB frame back.
        encoded = np.frombuffer(simplejpeg.encode_jpeg(frame, quality=quality, colorspace="BGR"), np.uint8)
        if encoded.size > dataset.shape[1]:
            dataset.resize(encoded.size, axis=1)
        dataset[i, : encoded.size] = encoded
        lengths[number, i] = encoded.size
