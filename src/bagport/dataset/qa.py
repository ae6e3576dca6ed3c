"""The dataset's QA record: ``meta/qa/`` beside (never inside) ``info.json``.

```
meta/qa/chunk-000/file-NNN.parquet   run NNN: one row per episode and check (value, verdict, reason, robot_id)
meta/qa/index/run-NNN.parquet        run NNN: one compact row per episode (bagport.qa.fleet.INDEX_SCHEMA)
meta/qa/details/run-NNN/PPPPPP.html  a warned or failed episode's page: checks, plots, thumbnails
meta/qa/summary.json                 per bag: episode index (null when excluded), score, verdict, reason,
                                     metadata (manifest columns such as robot_id, the events' episode_id)
meta/qa/report.html                  the fleet report over the whole dataset (bagport.qa.fleet)
```
Excluded bags and bags that could not be converted are listed too, with the reason. Each run adds its
own table, index and detail files; ``summary.json`` and ``report.html`` are rebuilt from the index files
alone, so an append never reads the old episodes' checks or plots. A run's entries may hold only a
digest of each staged episode's QA (:meth:`bagport.qa.QAEntry.of_staged`): the table and the detail pages
read each record back once, one episode at a time, so the commit's memory does not grow with the fleet.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.free_memory import release_unused_memory
from bagport.dataset.meta import EpisodeStats
from bagport.dataset.sketches import DatasetSketches
from bagport.qa import QABrief, QAConfig, QAEntry
from bagport.qa.fleet import INDEX_SCHEMA, detail_path, index_table, metadata_json, render_fleet_page
from bagport.qa.jumps import step_outlier_checks
from bagport.qa.report import Names, render_episode_page
from bagport.staging import StagedFeature

__all__ = [
    "QA_INDEX_PATH",
    "QA_REPORT_PATH",
    "QA_SUMMARY_PATH",
    "QA_TABLE_PATH",
    "QAEntry",
    "add_fleet_checks",
    "qa_rows",
    "write_qa",
]

QA_TABLE_PATH = "meta/qa/chunk-000/file-000.parquet"
QA_SUMMARY_PATH = "meta/qa/summary.json"
QA_REPORT_PATH = "meta/qa/report.html"
QA_INDEX_PATH = "meta/qa/index/run-{run:03d}.parquet"
_BRIEF_KEYS = tuple(f.name for f in fields(QABrief) if f.name in INDEX_SCHEMA.names)
"""A :class:`~bagport.qa.QABrief`'s fields the QA index keeps (all but its source stamp; the metadata as JSON), in
the brief's order: one ``summary.json`` episode."""


QA_TABLE_GROUP_ROWS = 4_096
"""Rows of this run's QA table written at a time (a row group): the checks of a whole fleet are never
held at once."""

_QA_FIELDS: list[tuple[str, pa.DataType]] = [
    ("bag_uri", pa.string()),
    ("episode_index", pa.int64()),
    ("excluded", pa.bool_()),
    ("check", pa.string()),
    ("subject", pa.string()),
    ("value", pa.float64()),
    ("verdict", pa.string()),
    ("hard", pa.bool_()),
    ("reason", pa.string()),
    ("robot_id", pa.string()),
]
QA_SCHEMA = pa.schema(_QA_FIELDS)


def add_fleet_checks(
    entries: Sequence[QAEntry],
    episode_stats: Sequence[EpisodeStats],
    sketches: DatasetSketches,
    features: Sequence[StagedFeature],
    config: dict[str, Any],
    fps: int,
) -> list[QAEntry]:
    """The entries with the checks that need the whole fleet (:mod:`bagport.qa.jumps`) added to each
    kept episode of this run (``episode_index`` counts this run's kept episodes, as ``episode_stats``)."""
    values = QAConfig.model_validate(config).values
    names = {f.key: f.names for f in features}
    out = []
    for entry in entries:
        if entry.episode_index is None:
            out.append(entry)
            continue
        stats = episode_stats[entry.episode_index]
        extra = step_outlier_checks(stats.largest_steps, sketches.steps, names, values, fps)
        out.append(entry.with_checks(extra))
    return out


def qa_rows(entries: Sequence[QAEntry]) -> pa.Table:
    """The QA table's rows of ``entries`` (whole ones: :meth:`QAEntry.whole`), one per episode and check."""
    rows: dict[str, list[Any]] = {name: [] for name in QA_SCHEMA.names}
    for entry in entries:
        robot = entry.metadata.get("robot_id")
        for check in entry.qa.checks:
            rows["bag_uri"].append(entry.qa.bag_uri)
            rows["episode_index"].append(entry.episode_index)
            rows["excluded"].append(entry.episode_index is None)
            rows["check"].append(check.check)
            rows["subject"].append(check.subject)
            rows["value"].append(check.value)
            rows["verdict"].append(check.verdict)
            rows["hard"].append(check.hard)
            rows["reason"].append(check.reason)
            rows["robot_id"].append(None if robot is None else str(robot))
    return pa.table(rows, schema=QA_SCHEMA)


def _write_run_pages(
    root: Path, entries: Sequence[QAEntry], run_number: int, names: Names | None, fps: int | None
) -> None:
    """This run's QA table and detail pages, in one pass: each entry's whole record (a digest entry's read
    back from the staging store, once) gives its checks' rows (Arrow at once: no Python object of the
    record outlives it, so the records' memory is reused) and, when it warned or failed, its page; at
    most :data:`QA_TABLE_GROUP_ROWS` rows are held, so memory does not grow with the fleet."""
    table_path = root / QA_TABLE_PATH.replace("file-000", f"file-{run_number:03d}")
    table_path.parent.mkdir(parents=True, exist_ok=True)
    group: list[pa.Table] = []
    written = 0
    with pq.ParquetWriter(table_path, QA_SCHEMA, compression="zstd") as writer:
        for position, entry in enumerate(entries):
            whole = entry.whole()
            group.append(qa_rows([whole]))
            if whole.qa.verdict != "pass":
                page = root / "meta/qa" / detail_path(run_number, position)
                page.parent.mkdir(parents=True, exist_ok=True)
                page.write_text(render_episode_page(whole, names, fps, "../../report.html"), encoding="utf-8")
            if sum(len(t) for t in group) >= QA_TABLE_GROUP_ROWS:
                writer.write_table(pa.concat_tables(group).combine_chunks())
                group, written = [], written + 1
        if group or not written:
            writer.write_table(pa.concat_tables(group).combine_chunks() if group else qa_rows([]))


def _migrate_legacy_summary(root: Path, run_number: int, previous: str) -> None:
    """A dataset written before the QA index existed: its ``summary.json`` (every earlier run's episodes)
    becomes ``index/run-000.parquet``, once (their checks lists are not known: empty)."""
    fs, before = url_to_fs(previous)
    summary_path = f"{before}/{QA_SUMMARY_PATH}"
    legacy_path = root / QA_INDEX_PATH.format(run=0)
    if not run_number or fs.isfile(f"{before}/{QA_INDEX_PATH.format(run=0)}") or not fs.isfile(summary_path):
        return
    with fs.open(summary_path, "r", encoding="utf-8") as handle:
        legacy = json.load(handle).get("episodes", [])
    rows = [
        {**{k: e.get(k) for k in _BRIEF_KEYS}, "metadata": metadata_json(e.get("metadata")), "run": 0,
         "position": n, "name": str(e["bag_uri"]).rsplit("/", 1)[-1],
         "robot_type": "", "folder": str(e["bag_uri"]).rsplit("/", 1)[0], "day": "unknown",
         "fails": [], "warns": [], "detail": False}
        for n, e in enumerate(legacy)
    ]  # fmt: skip
    legacy_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows, schema=INDEX_SCHEMA), legacy_path, compression="zstd")


def _index_tables(root: Path, previous: str | None, run_number: int, index: pa.Table) -> list[pa.Table]:
    """Every run's QA index, in run order: this run's (``index``, as written under ``root``), the others
    under ``root`` (a legacy ``run-000``) and the earlier ones (``previous``)."""
    this_run = QA_INDEX_PATH.format(run=run_number).rsplit("/", 1)[-1]
    mine = {p.name: p for p in (root / "meta/qa/index").glob("run-*.parquet")}
    fs, before = url_to_fs(previous or str(root))
    theirs = {
        name: str(path)
        for path in fs.glob(f"{before.rstrip('/')}/meta/qa/index/run-*.parquet")
        if (name := str(path).rsplit("/", 1)[-1]) not in mine
    }
    tables = []
    for name in sorted([*mine, *theirs]):
        if name == this_run:
            tables.append(index)
        elif name in mine:
            tables.append(pq.read_table(mine[name], schema=INDEX_SCHEMA))
        else:
            with fs.open(theirs[name], "rb") as handle:
                tables.append(pq.read_table(handle, schema=INDEX_SCHEMA))
    return tables


def write_qa(
    root: Path,
    entries: Sequence[QAEntry],
    dataset: dict[str, Any],
    config: dict[str, Any],
    run_number: int = 0,
    *,
    robot_type: str = "",
    names: Names | None = None,
    previous: str | None = None,
) -> str:
    """Write this run's QA table, index and detail pages under ``root/meta/qa``, then rebuild the summary
    and the fleet report over every run from the index files (the earlier runs' at ``previous``, the
    dataset's root as a path or URI, when this run builds its ``meta/`` apart from it; default ``root``).
    Returns the report's path in the dataset."""
    fps = dataset.get("fps")
    _write_run_pages(root, entries, run_number, names, int(fps) if fps else None)
    release_unused_memory()
    _migrate_legacy_summary(root, run_number, previous or str(root))
    index = index_table(entries, run_number, robot_type)
    index_path = root / QA_INDEX_PATH.format(run=run_number)
    index_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(index, index_path, compression="zstd")
    release_unused_memory()
    whole = pa.concat_tables(_index_tables(root, previous, run_number, index))
    _write_summary(root, whole, config)
    (root / QA_REPORT_PATH).write_text(render_fleet_page(whole, dataset, run_number), encoding="utf-8")
    return QA_REPORT_PATH


def _write_summary(root: Path, index: pa.Table, config: dict[str, Any]) -> None:
    """``summary.json`` from every run's index (its rows gone before the fleet page builds its own)."""
    episodes = [
        {**{k: row[k] for k in _BRIEF_KEYS}, "metadata": json.loads(row["metadata"] or "{}")}
        for row in index.select(list(_BRIEF_KEYS)).to_pylist()
    ]
    summary = {
        "episodes": episodes,
        "kept": sum(e["episode_index"] is not None for e in episodes),
        "excluded": sum(e["episode_index"] is None for e in episodes),
        "thresholds": config,
        "reports": [QA_REPORT_PATH.removeprefix("meta/qa/")],
    }
    (root / QA_SUMMARY_PATH).write_text(json.dumps(summary, indent=1))
