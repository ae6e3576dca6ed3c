"""The staged artifact of one episode, shared between workers through fsspec.

```
<staging>/episodes/<episode_id>/
    frames.parquet        timestamp, frame_index, task, one column per vector feature
    qa.json               QA checks (value, verdict, reason), score, and small series for the report
    provenance.parquet    per frame and source: topic, log time, header stamp, stamp used
    stats.json            per-feature stats partials (+ pixel histograms for videos)
    videos/<key>.mp4      one clip per camera, pts = frame index
    episode.json          the summary; written last, so its presence marks completion
<staging>/segments/<bag>-<key>.json   a bag's episode windows (``bagport.segment.cache``)
```
"""

from __future__ import annotations

import json
import os
import posixpath
import threading
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import fsspec
import pyarrow as pa
import pyarrow.parquet as pq
from fsspec.core import url_to_fs
from pydantic import JsonValue

from bagport.errors import TransientError
from bagport.timewindow import WindowNs
from bagport.uris import is_local

__all__ = [
    "EPISODE_SUMMARY",
    "EpisodeSummary",
    "StagedFeature",
    "episode_dir",
    "read_staged_table",
    "read_summary",
    "replace_whole",
    "staged_path",
    "write_json",
]

EPISODE_SUMMARY = "episode.json"
FRAMES_FILE = "frames.parquet"
PROVENANCE_FILE = "provenance.parquet"
STATS_FILE = "stats.json"
QA_FILE = "qa.json"


@dataclass(frozen=True, slots=True)
class StagedFeature:
    key: str
    dtype: str
    shape: tuple[int, ...]
    names: tuple[str, ...] | None
    video_info: dict[str, JsonValue] | None = None
    sources: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class EpisodeSummary:
    """Everything the reduce step needs to know about one staged episode."""

    episode_id: str
    dir_uri: str
    bag_uri: str
    storage: str
    bag_size_bytes: int
    bag_fingerprint: str
    manifest_entry: int
    fps: int
    frames: int
    first_tick_ns: int
    last_tick_ns: int
    tasks: tuple[str, ...]
    task_source: str
    features: tuple[StagedFeature, ...]
    stamp_sources: dict[str, str]
    videos: dict[str, str]
    metadata: dict[str, JsonValue] = field(default_factory=dict)
    bagport_version: str = ""
    contract_sha256: str = ""
    source_stamp: str = ""
    """Names, sizes and modification times of the bag's files when it was converted."""
    default_task: str | None = None
    alignment: list[dict[str, Any]] = field(default_factory=list)
    """Per source: stamp, strategy, fill, alignment error (ms), held/interpolated/filled/dropped frames."""
    qa: dict[str, Any] = field(default_factory=dict)
    """QA score, verdict and the checks that did not pass (the full record is ``qa.json``)."""
    qa_sha256: str = ""
    window_ns: WindowNs | None = None
    """The episode's window in bag log time when the bag holds several episodes (or a manifest window)."""
    segment: int | None = None
    label: str | None = None
    """``success``, ``failed``, ``discarded`` (episode events), or ``None``."""
    note: str = ""
    bag_read: dict[str, Any] = field(default_factory=dict)
    """How the bag was read: access (local, download, ranged), bytes_read, requests, warnings."""
    clip_keys: dict[str, str] = field(default_factory=dict)
    """Per camera: what its clip depends on (``bagport.episode.reuse``); equal keys, equal clips."""
    reused_clips: dict[str, str] = field(default_factory=dict)
    """Per camera whose clip was copied from an earlier staged episode of the bag: that episode's id."""
    data_bytes: int | None = None
    """The episode's row group in a data file, in bytes, as the worker encoded it (indices from 0: the
    final ones change it by a few bytes); the reduce plans the data files from it. ``None`` in a summary
    staged before bagport recorded it (the reduce then uses the staged frame table's size)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EpisodeSummary:
        features = tuple(
            StagedFeature(
                key=f["key"],
                dtype=f["dtype"],
                shape=tuple(f["shape"]),
                names=tuple(f["names"]) if f["names"] is not None else None,
                video_info=f.get("video_info"),
                sources=tuple(f.get("sources", ())),
            )
            for f in data["features"]
        )
        values = {k: v for k, v in data.items() if k != "features"}
        values["tasks"] = tuple(values["tasks"])
        if values.get("window_ns") is not None:
            values["window_ns"] = tuple(values["window_ns"])
        return cls(features=features, **values)

    def file(self, name: str) -> str:
        return staged_path(self.dir_uri, name)


def episode_dir(staging_uri: str, episode_id: str) -> str:
    return staged_path(staging_uri, "episodes", episode_id)


def staged_path(base: str, *parts: str) -> str:
    return posixpath.join(base.rstrip("/"), *parts)


def write_json(uri: str, data: Any) -> None:
    """``data`` as JSON at ``uri``, whole or not at all. On the local disk it is written beside its place
    and renamed there: a run killed while writing an episode's summary (its completion marker) left it
    cut short, and the next run failed on it instead of converting the episode again. An object store's
    write (one PUT) is whole already."""
    fs, path = url_to_fs(uri)
    fs.makedirs(posixpath.dirname(path), exist_ok=True)
    text = json.dumps(data, indent=1, sort_keys=False)
    try:
        if is_local(fs):
            replace_whole(Path(path), text)
        else:
            with fs.open(path, "w", encoding="utf-8") as handle:
                handle.write(text)
    except ConnectionError as err:
        raise TransientError(f"{uri}: write failed ({err}); try again") from err


def replace_whole(path: Path, text: str) -> None:
    """``text`` at the local ``path``, whole or not at all: written beside it under a name of this process
    and thread (two writers of one path never share one; the file gets the usual permissions, as any
    file this process creates), then renamed over it; on failure that file is removed."""
    partial = path.with_name(f"{path.name}.partial-{os.getpid()}-{threading.get_ident()}")
    try:
        partial.write_text(text, encoding="utf-8")
        partial.replace(path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def read_staged_table(uri: str) -> pa.Table:
    """A staged Parquet file (an episode's frames or provenance), whole.

    Read as one file (``ParquetFile``), not through ``pq.read_table``'s dataset layer: for an episode's
    small file that layer is three quarters of the cost (1.0 against 0.24 ms), paid for every episode by
    the reduce.
    """
    fs, path = url_to_fs(uri)
    with fs.open(path, "rb") as handle:
        return pq.ParquetFile(handle).read()


def read_summary(dir_uri: str) -> EpisodeSummary | None:
    """The summary of a completed staged episode, or ``None`` if it never completed: no summary, or one
    that cannot be read (cut short by a run killed while an older bagport wrote it; as the plan does, such
    an episode is converted again, which rewrites it)."""
    uri = staged_path(dir_uri, EPISODE_SUMMARY)
    try:
        with fsspec.open(uri, "r", encoding="utf-8") as handle:
            return EpisodeSummary.from_dict(json.load(handle))
    except (FileNotFoundError, ValueError, KeyError, TypeError):
        return None
