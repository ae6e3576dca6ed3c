"""Which bags a dataset holds, in one table beside its run records (``meta/provenance/bags.parquet``).

An ``--append`` (every hour, for months) asks which bags the dataset holds already. Each run's record
answers for its own bags, so reading them all costs one request and one JSON parse per run ever made: a
year of hourly appends is 8,760 records and hundreds of megabytes. Every write that commits ``meta/``
therefore writes this table: one row per episode kept or bag left out, over every run up to its own
(``covered_run`` in the table's metadata). A run that writes no table (an append whose new bags were all
excluded records only its ``run-NNN.json``) or a dataset written before the table existed is read from
its records on top, so the table is never the only source: it is the records' cache.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from fsspec import AbstractFileSystem

from bagport.dataset.layout import BAGS_INDEX_PATH, run_number

__all__ = ["BAGS_SCHEMA", "bag_rows", "record_rows", "write_bags_index"]

_FIELDS: list[tuple[str, pa.DataType]] = [
    ("run", pa.int64()),
    ("kind", pa.string()),  # "kept" (an episode in the dataset) or "left_out" (excluded)
    ("bag_uri", pa.string()),
    ("window", pa.string()),  # the manifest window's key ("": the whole bag); null: a record without windows
    ("source_stamp", pa.string()),
    ("bag_fingerprint", pa.string()),
    ("staged_episode_id", pa.string()),
    ("removable", pa.bool_()),  # its run did not --keep-staging: a staged copy left behind may go
]
BAGS_SCHEMA = pa.schema(_FIELDS)
_COVERED = b"bagport.covered_run"


def record_rows(record: Mapping[str, Any], run: int) -> pa.Table:
    """The rows of one run record (its ``episodes`` kept, its ``excluded`` left out)."""
    windows = record.get("manifest", {}).get("windows")  # by manifest entry; absent in older records
    removable = record.get("keep_staging") is False  # older records say nothing: kept
    columns: dict[str, list[Any]] = {name: [] for name in BAGS_SCHEMA.names}
    entries = [("kept", e) for e in record.get("episodes", [])] + [
        ("left_out", e) for e in record.get("excluded", [])
    ]
    for kind, entry in entries:
        columns["run"].append(run)
        columns["kind"].append(kind)
        columns["bag_uri"].append(str(entry["bag_uri"]))
        columns["window"].append(
            None if windows is None else windows.get(str(entry.get("manifest_entry")), "")
        )
        # as the records were read before the table: a stamp recorded as null is "None", never a bag's stamp
        columns["source_stamp"].append(str(entry.get("source_stamp", "")))
        columns["bag_fingerprint"].append(str(entry.get("bag_fingerprint", "")))
        columns["staged_episode_id"].append(str(entry.get("staged_episode_id") or ""))
        columns["removable"].append(removable)
    return pa.table(columns, schema=BAGS_SCHEMA)


def _read_index(fs: AbstractFileSystem, root: str) -> tuple[pa.Table, int] | None:
    """The table and the last run it covers; ``None`` when there is none or it cannot be read (the run
    records say the same, slower)."""
    try:
        with fs.open(f"{root}/{BAGS_INDEX_PATH}", "rb") as handle:
            table = pq.read_table(handle)
        covered = int((table.schema.metadata or {})[_COVERED])
        return table.cast(BAGS_SCHEMA), covered
    except (FileNotFoundError, OSError, KeyError, ValueError, pa.ArrowException):
        return None


def bag_rows(fs: AbstractFileSystem, root: str) -> pa.Table:
    """Every bag row of the dataset at ``root`` (an fsspec path): the table's, then those of the run records
    it does not cover (read one by one)."""
    records = {
        run: str(path)
        for path in fs.glob(f"{root}/meta/provenance/run*.json")
        if (run := run_number(str(path))) is not None
    }
    tables: list[pa.Table] = []
    covered = -1
    index = _read_index(fs, root)
    if index is not None:
        tables.append(index[0])
        covered = index[1]
    for run in sorted(r for r in records if r > covered):
        with fs.open(records[run], "r", encoding="utf-8") as handle:
            tables.append(record_rows(json.load(handle), run))
    return pa.concat_tables(tables) if tables else BAGS_SCHEMA.empty_table()


def write_bags_index(path: Path, rows: pa.Table, covered_run: int) -> None:
    """Write ``rows`` (every run's up to ``covered_run``, this one's included) as the table at ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    table = rows.cast(BAGS_SCHEMA).replace_schema_metadata({_COVERED: str(covered_run).encode()})
    pq.write_table(table, path, compression="zstd")
