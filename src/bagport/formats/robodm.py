"""One Robo-DM trajectory per episode, from the staged episodes (``--format robodm``).

``episode_<i>.vla`` (Robo-DM's Matroska container, written with the ``robodm`` package) holds, per frame
and stamped with the frame's original time in the bag's log time (ns): every contract key under its own
name (``observation.state``, ``action``, ``observation.images.<camera>`` as RGB ``HxWx3`` uint8 decoded
from the staged clip), ``timestamp`` (LeRobot's, s), ``frame_index``, ``tick_ns`` (the original time
again, as a value), ``task`` and ``episode``: at the first frame a JSON text with the episode's
provenance (bag, window, label and note, manifest metadata, QA), fps, robot type and tasks, an empty text
at the others (a stream with one value only would make the muxer buffer every other stream).

Images are stored with Robo-DM's ``rawvideo`` codec (lossless, uncompressed): ``robodm`` 0.1.0 tests
its video codecs with ``CodecContext.close()``, which PyAV 14 removed, so with the PyAV bagport needs
(15) every video codec it offers is refused and it falls back to raw frames anyway.
"""

from __future__ import annotations

import itertools
import json
import logging
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bagport.dataset import DatasetReport
from bagport.errors import BagportError
from bagport.formats.frames import episode_record, iter_tick_batches, iter_vector_batches, iter_video_frames
from bagport.formats.meta import write_format_meta
from bagport.formats.publish import publish_built
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

__all__ = ["write_robodm_dataset"]

CODEC = "rawvideo"


class RobodmMissingError(BagportError):
    """``--format robodm`` without the robodm package installed."""

    def __init__(self, missing: str) -> None:
        super().__init__(
            f"--format robodm needs the robodm package, which is not installed here ({missing}). Fix: pip install "
            "'bagport[robodm]' (uv sync --extra robodm; make setup installs every extra), or leave robodm out of "
            "--format."
        )


def trajectory_class() -> Any:
    """``robodm.Trajectory``, imported without letting robodm reconfigure the process's logging (its
    import sets the root logger to INFO and installs a handler)."""
    root = logging.getLogger()
    level, handlers = root.level, list(root.handlers)
    try:
        import robodm  # noqa: PLC0415 - an optional extra
    except ImportError as err:
        raise RobodmMissingError(str(err)) from err
    finally:
        root.setLevel(level)
        root.handlers[:] = handlers
    logging.getLogger("robodm").setLevel(logging.WARNING)
    return robodm.Trajectory


def write_robodm_dataset(
    summaries: Sequence[EpisodeSummary],
    output: str,
    *,
    robot_type: str,
    run_record: dict[str, Any],
    overwrite: bool = False,
    qa: Sequence[QAEntry] = (),
) -> DatasetReport:
    """Write ``output``/``episode_<i>.vla`` for each summary, plus ``meta/`` (published atomically)."""
    trajectory = trajectory_class()
    features = {
        f.key: {
            "dtype": "uint8" if f.video_info is not None else f.dtype,
            "shape": list(f.shape),
            "names": list(f.names) if f.names is not None else None,
        }
        for f in summaries[0].features
    }

    def build(root: Path) -> DatasetReport:
        files = []
        for index, summary in enumerate(summaries):
            name = f"episode_{index}.vla"
            _write_trajectory(trajectory, root / name, summary, index, robot_type)
            files.append(name)
        return write_format_meta(
            root,
            "robodm",
            summaries,
            files,
            robot_type=robot_type,
            features=features,
            run_record=run_record,
            qa=qa,
            extra={"image_codec": CODEC, "time_unit": "ns", "timestamps": "tick_ns (bag log time)"},
        )

    return replace(publish_built(output, overwrite=overwrite, build=build), root=output)


def _rows(summary: EpisodeSummary) -> Iterator[tuple[float, int, str, dict[str, Any]]]:
    for batch in iter_vector_batches(summary):
        for i in range(batch.timestamp.size):
            values = {key: column[i] for key, column in batch.values.items()}
            yield float(batch.timestamp[i]), int(batch.frame_index[i]), batch.task[i], values


def _write_trajectory(
    trajectory: Any, path: Path, summary: EpisodeSummary, index: int, robot_type: str
) -> None:
    cameras = {f.key: iter_video_frames(summary, f.key) for f in summary.features if f.video_info is not None}
    ticks = itertools.chain.from_iterable(iter_tick_batches(summary))
    episode = {
        **episode_record(summary, index),
        "fps": summary.fps,
        "robot_type": robot_type,
        "tasks": list(summary.tasks),
    }
    writer = trajectory(str(path), mode="w", video_codec=CODEC, time_unit="ns")
    try:
        for (timestamp, frame_index, task, values), tick in zip(_rows(summary), ticks, strict=True):
            stamp_ns = int(tick)

            def add(name: str, value: Any, stamp_ns: int = stamp_ns) -> None:
                writer.add(name, value, timestamp=stamp_ns, time_unit="ns")

            # one value per frame: a stream with a single packet holds back the muxer's interleaving, which
            # then buffers every other stream's packets (up to FFmpeg's 10 s), so memory would grow
            add("episode", json.dumps(episode, default=str) if frame_index == 0 else "")
            add("timestamp", np.float32(timestamp))
            add("frame_index", np.int64(frame_index))
            add("tick_ns", np.int64(stamp_ns))
            add("task", task)
            for key, value in values.items():
                add(key, value)
            for key, frames in cameras.items():
                add(key, next(frames))
        for frames in cameras.values():
            next(frames, None)  # the clip's own check: exactly as many frames as the episode
    finally:
        writer.close(compact=False)  # nothing to transcode: every stream is rawvideo already
