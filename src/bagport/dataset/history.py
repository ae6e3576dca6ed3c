"""Which bags a dataset already holds, from its provenance run records (for appends and ingestion)."""

from __future__ import annotations

import json
from typing import Any

import pandas as pd
from fsspec.core import url_to_fs

from bagport.dataset.base import read_base, record_head, record_string, record_tail
from bagport.dataset.checksums import latest_record
from bagport.dataset.layout import (
    APPEND_RUN_RECORD_PATH,
    INFO_PATH,
    JOURNAL_PATH,
    RUN_RECORD_PATH,
    TASKS_PATH,
)
from bagport.dataset.write import DatasetReport

__all__ = ["converted_bags", "dataset_report", "record_exclusions", "recorded_failures", "recorded_write_key"]


def converted_bags(root: str) -> set[tuple[str, str]]:
    """``(bag URI, source stamp)`` of every episode in the dataset at ``root``.

    Bags a run excluded (failed QA or conversion) are in the set too, so an unchanged bad bag is not
    retried by every scheduled run; a bag re-recorded or changed since (another stamp) converts again, as
    does one whose failure was not its own (recorded without a stamp: a transient I/O error).
    """
    fs, path = url_to_fs(root)
    found: set[tuple[str, str]] = set()
    for record_path in fs.glob(f"{path.rstrip('/')}/meta/provenance/run*.json"):
        with fs.open(record_path, "r", encoding="utf-8") as handle:
            record = json.load(handle)
        for episode in [*record.get("episodes", []), *record.get("excluded", [])]:
            found.add((str(episode["bag_uri"]), str(episode.get("source_stamp", ""))))
    return found


def dataset_report(root: str) -> DatasetReport:
    """The report of a dataset as it stands (a run that had nothing new to add)."""
    fs, path = url_to_fs(root)
    with fs.open(f"{path.rstrip('/')}/{INFO_PATH}", "r", encoding="utf-8") as handle:
        info = json.load(handle)
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
    unchanged bad bag from being retried by every scheduled run (see :func:`converted_bags`)."""
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
