"""The dataset's provenance log: every frame traced to its bag, topic and times.

``meta/provenance/chunk-000/file-000.parquet`` has one row per frame and contract
source (``episode_index, index, frame_index, key, topic, tick_ns, source_log_ns,
source_header_ns, stamp_used, message_index``); ``meta/provenance/run.json``
records the run: contract and manifest snapshots, bag URIs and fingerprints,
grid start/end per episode, bagport version and encoder settings.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bagport.dataset.base import DatasetBase
from bagport.dataset.data_files import DataPlacement
from bagport.dataset.layout import APPEND_RUN_RECORD_PATH, PROVENANCE_PATH, RUN_RECORD_PATH
from bagport.errors import DatasetWriteError
from bagport.staging import PROVENANCE_FILE, EpisodeSummary, read_staged_table, read_summary

__all__ = ["episode_provenance", "run_record_path", "write_provenance", "write_run_record"]


def run_record_path(base: DatasetBase | None) -> str:
    """This run's record, relative to the dataset root (``run.json``; an append's ``run-NNN.json``)."""
    return RUN_RECORD_PATH if base is None else APPEND_RUN_RECORD_PATH.format(run=base.run_number)


def episode_provenance(s: EpisodeSummary, i: int) -> dict[str, Any]:
    """Where episode ``i`` came from (its entry in ``meta/provenance/run.json``; other formats write it too).
    A summary the reduce holds lean (no alignment or QA digest: :func:`bagport.reduce.read_staged`) gets
    them back from its staged ``episode.json``, one episode at a time as the record is written."""
    if not s.qa:
        staged = read_summary(s.dir_uri)
        if staged is None:
            raise DatasetWriteError(
                f"the staged episode {s.dir_uri} (from {s.bag_uri}) is gone or its episode.json unreadable "
                "since this run selected it, so its provenance cannot be written; nothing was published. Fix: "
                "re-run the conversion (it stages the episode again), and keep other runs from cleaning this "
                "staging store meanwhile."
            )
        s = replace(s, alignment=staged.alignment, qa=staged.qa)
    return {
        "episode_index": i,
        "bag_uri": s.bag_uri,
        "storage": s.storage,
        "bag_size_bytes": s.bag_size_bytes,
        "bag_fingerprint": s.bag_fingerprint,
        "source_stamp": s.source_stamp,
        "bag_read": s.bag_read,
        "manifest_entry": s.manifest_entry,
        "staged_episode_id": s.episode_id,
        "frames": s.frames,
        "first_tick_ns": s.first_tick_ns,
        "last_tick_ns": s.last_tick_ns,
        "task_source": s.task_source,
        "stamp_sources": s.stamp_sources,
        "alignment": s.alignment,
        "qa": s.qa,
        "metadata": s.metadata,
        "segment": s.segment,
        "window_ns": list(s.window_ns) if s.window_ns is not None else None,
        "label": s.label,
        "label_note": s.note,
        "reused_clips": dict(s.reused_clips),  # camera key -> the staged episode its clip came from
    }


def write_provenance(
    root: Path,
    summaries: Sequence[EpisodeSummary],
    data: Sequence[DataPlacement],
    run_record: dict[str, Any],
    base: DatasetBase | None = None,
    *,
    record: bool = True,
) -> None:
    """Write this run's provenance rows and (with ``record``) run record; an append adds a new file and
    ``run-NNN.json``. Without ``record`` the caller writes the record later (:func:`write_run_record`)."""
    first_episode = base.episodes if base is not None else 0
    chunk, file = base.next_provenance if base is not None else (0, 0)
    path = root / PROVENANCE_PATH.format(chunk_index=chunk, file_index=file)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer: pq.ParquetWriter | None = None
    pending: list[pa.Table] = []
    try:
        for episode_index, (summary, placement) in enumerate(
            zip(summaries, data, strict=True), first_episode
        ):
            pending.append(_episode_rows(summary, placement, episode_index))
            if writer is None:
                writer = pq.ParquetWriter(path, pending[0].schema, compression="zstd")
            if sum(t.num_rows for t in pending) >= PROVENANCE_GROUP_ROWS:
                _write_group(writer, pending)
        if writer is not None and pending:
            _write_group(writer, pending)
    finally:
        if writer is not None:
            writer.close()
    if record:
        episodes = (episode_provenance(s, i) for i, s in enumerate(summaries, first_episode))
        write_run_record(root / run_record_path(base), run_record, episodes, {})


PROVENANCE_GROUP_ROWS = 4_096
"""Provenance rows per row group (several episodes each: a writer keeps every row group's metadata until
it closes, so one row group per episode would grow the commit's memory with the number of episodes)."""


def _episode_rows(summary: EpisodeSummary, placement: DataPlacement, episode_index: int) -> pa.Table:
    table = read_staged_table(summary.file(PROVENANCE_FILE))
    frame_index = table.column("frame_index").to_numpy()
    table = table.add_column(0, "index", pa.array(placement.from_index + frame_index.astype(np.int64)))
    return table.add_column(0, "episode_index", pa.array(np.full(table.num_rows, episode_index, np.int64)))


def _write_group(writer: pq.ParquetWriter, pending: list[pa.Table]) -> None:
    """The pending episodes' rows as one row group (their dictionaries unified); empties ``pending``."""
    group = pa.concat_tables(pending).unify_dictionaries().combine_chunks()
    writer.write_table(group, row_group_size=max(1, group.num_rows))
    pending.clear()


def _nested(value: Any, level: int) -> str:
    return json.dumps(value, indent=2, default=str).replace("\n", "\n" + "  " * level)


def write_run_record(
    path: Path, record: dict[str, Any], episodes: Iterable[dict[str, Any]], tail: dict[str, Any]
) -> None:
    """Write ``json.dumps({**record, "episodes": [...], **tail}, indent=2, default=str)``, one episode's
    entry at a time (memory stays flat in the number of episodes)."""
    with path.open("w", encoding="utf-8") as out:
        out.write("{")
        for n, (key, value) in enumerate([*record.items(), ("episodes", None), *tail.items()]):
            out.write(("\n" if n == 0 else ",\n") + f"  {json.dumps(key)}: ")
            if key != "episodes" or value is not None:
                out.write(_nested(value, 1))
                continue
            count = 0
            for count, entry in enumerate(episodes, 1):
                out.write(("[\n    " if count == 1 else ",\n    ") + _nested(entry, 2))
            out.write("\n  ]" if count else "[]")
        out.write("\n}")
