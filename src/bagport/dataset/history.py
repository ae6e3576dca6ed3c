"""Which bags a dataset already holds, from its provenance run records (for appends and ingestion)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import pandas as pd
from fsspec.core import url_to_fs

from bagport.dataset.bags_index import BAGS_SCHEMA, bag_rows
from bagport.dataset.base import read_base, read_info, record_head, record_string, record_tail
from bagport.dataset.checksums import latest_record
from bagport.dataset.layout import (
    APPEND_RUN_RECORD_PATH,
    JOURNAL_PATH,
    RUN_RECORD_PATH,
    TASKS_PATH,
)
from bagport.dataset.write import DatasetReport

__all__ = [
    "DatasetBags",
    "dataset_bags",
    "dataset_report",
    "record_exclusions",
    "recorded_failures",
    "recorded_write_key",
]


@dataclass(frozen=True, slots=True)
class DatasetBags:
    """What a dataset's run records say of its bags, each by URI and manifest window (the window's key;
    ``None`` in a record written before windows were recorded: any window of the bag)."""

    kept: dict[tuple[str, str | None], dict[str, str]] = field(default_factory=dict)
    """Bags with an episode in the dataset: ``{(URI, window): {source stamp: bag fingerprint}}``."""
    left_out: set[tuple[str, str | None, str]] = field(default_factory=set)
    """Bags a run excluded (failed QA or conversion), with the stamp of the files then."""
    committed_staged: set[tuple[str, str]] = field(default_factory=set)
    """``(staged episode id, source stamp)`` of the dataset's episodes, from the runs that did not ``--keep-staging`` (older
    records say nothing: kept) other than the newest that added episodes: a staged episode still there under
    one of them was left by a run killed after its commit."""
    newest_staged: set[tuple[str, str]] = field(default_factory=set)
    """The same of the newest run that added episodes, which may still be finishing (other formats read its
    staged episodes after its commit) unless the output's recovery found no live write."""

    def kept_as(self, uri: str, window: str) -> dict[str, str] | None:
        """The stamps and fingerprints the bag's window was appended with, or ``None`` when it was not."""
        found = [self.kept[k] for k in ((uri, window), (uri, None)) if k in self.kept]
        return {stamp: fp for stamps in found for stamp, fp in stamps.items()} if found else None

    def left_out_unchanged(self, uri: str, window: str, stamp: str) -> bool:
        """The bag's window was left out by a run when its files had this stamp (it would fail again)."""
        return (uri, window, stamp) in self.left_out or (uri, None, stamp) in self.left_out


def dataset_bags(root: str) -> DatasetBags:
    """The bags of every run of the dataset at ``root`` (its bags table, then the records it does not cover:
    :mod:`bagport.dataset.bags_index`): kept (an episode in the dataset) or left out. A bag left out
    converts again once its files change (another stamp), or when its failure was not its own (recorded
    without a stamp: a transient I/O error)."""
    fs, path = url_to_fs(root)
    rows = bag_rows(fs, path.rstrip("/"))
    bags = DatasetBags()
    columns: list[list[Any]] = [rows.column(name).to_pylist() for name in BAGS_SCHEMA.names]
    # the newest run that added episodes (a later one that only recorded exclusions staged nothing)
    added = [run for run, kind in zip(columns[0], columns[1], strict=True) if kind == "kept"]
    newest = max(added) if added else None
    for run, kind, uri, window, stamp, fingerprint, staged_id, removable in zip(*columns, strict=True):
        if kind == "left_out":
            bags.left_out.add((uri, window, stamp))
            continue
        bags.kept.setdefault((uri, window), {})[stamp] = fingerprint
        if removable and staged_id:
            (bags.newest_staged if run == newest else bags.committed_staged).add((staged_id, stamp))
    return bags


def dataset_report(root: str) -> DatasetReport:
    """The report of a dataset as it stands (a run that had nothing new to add)."""
    fs, path = url_to_fs(root)
    info = read_info(root)
    tasks = pd.read_parquet(f"{root.rstrip('/')}/{TASKS_PATH}", storage_options=fs.storage_options)
    videos = tuple(k for k, f in info["features"].items() if f.get("dtype") == "video")
    size = sum(int(fs.size(p)) for p in fs.find(path))
    frames = int(info["total_frames"])
    return DatasetReport(
        root,
        int(info["total_episodes"]),
        frames,
        tuple(str(t) for t in tasks.index),
        videos,
        size,
        frames / info["fps"],
    )


def record_exclusions(root: str, run_record: dict[str, Any]) -> str:
    """Record an append run that kept no episode (its bags were all excluded) as the next
    ``run-NNN.json``, data untouched; the URI of the record. Its ``excluded`` entries keep an
    unchanged bad bag from being retried by every scheduled run (see :func:`dataset_bags`)."""
    fs, path = url_to_fs(root)
    run = read_base(root).run_number
    record_path = f"{path.rstrip('/')}/{APPEND_RUN_RECORD_PATH.format(run=run)}"
    with fs.open(record_path, "w", encoding="utf-8") as handle:
        json.dump({**run_record, "episodes": []}, handle, indent=2, default=str)
    return str(fs.unstrip_protocol(record_path))


def recorded_write_key(root: str) -> str | None:
    """The write key of the run that wrote the dataset at ``root`` as it stands, or ``None`` when it
    cannot be trusted to be that run's output without writing it again.

    Cheap, from one listing of the dataset (no file is hashed): no write is pending (no intent
    record, no half-done replace or append); the newest run record is ``run.json`` (no append since)
    and holds a ``write_key``; every file it lists is there and nothing unlisted sits under ``data/``
    or ``videos/`` (what LeRobot would read). ``bagport validate`` hashes every file.
    """
    fs, path = url_to_fs(root)
    base = path.rstrip("/")
    try:
        listed = {str(p)[len(base) + 1 :] for p in fs.find(base)}
    except (FileNotFoundError, NotADirectoryError):
        return None
    if not listed or JOURNAL_PATH in listed or any(".old-" in p for p in listed):
        return None
    if latest_record([p for p in listed if p.startswith("meta/provenance/")]) != RUN_RECORD_PATH:
        return None
    with fs.open(f"{base}/{RUN_RECORD_PATH}", "rb") as handle:
        raw = handle.read()
    key = record_string(raw, "write_key")
    tail = record_tail(raw)  # the record's episodes are not parsed
    files = set(tail.get("files", {}))
    if key is None or not files or not tail.get("files_complete", False):
        return None
    readable = {p for p in listed if p.startswith(("data/", "videos/"))}
    if not files <= listed or not readable <= files:
        return None
    return key


def recorded_failures(root: str) -> list[dict[str, Any]]:
    """The bags the run that wrote the dataset at ``root`` could not convert for their own sake (its run
    record's ``failures``: manifest entry, bag URI, segment, error, the bag's source stamp then); a
    failure that was not the bag's (a transient I/O error) is not among them. Empty when none is recorded."""
    fs, path = url_to_fs(root)
    try:
        with fs.open(f"{path.rstrip('/')}/{RUN_RECORD_PATH}", "rb") as handle:
            raw = handle.read()
    except FileNotFoundError:
        return []
    failures = record_head(raw).get("failures", [])
    return [f for f in failures if isinstance(f, dict)] if isinstance(failures, list) else []
