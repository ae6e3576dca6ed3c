"""The fleet manifest as CSV, as the ROS bag guide bagport follows recommends ("a manifest CSV mapping
bag paths to metadata: robot ID, task type, collection date").

```csv
uri,task,robot_id,collection_date,start_s,end_s
bags/episode_000,pick up the red cube,arm-07,2026-11-02,,
s3://fleet/2026-11-*/*.mcap,,arm-09,2026-11-03,,
bags/long_session,fold the towel,arm-07,2026-11-02,12.5,47.0
```

A header row names the columns: ``uri`` (required), ``task``, the window columns ``start_s``/``end_s``
(or ``start_ns``/``end_ns``), and every other column goes into the entry's ``metadata`` as text
(``robot_id``, ``collection_date``...). An empty cell is an absent value. Errors name the row (the
header is row 1) and the column instead of ``bags[i]``.
"""

from __future__ import annotations

import csv
import io
from typing import Any

from bagport.errors import ManifestError

__all__ = ["CSV_FIELDS", "csv_entries"]

CSV_FIELDS = ("uri", "task", "start_s", "end_s", "start_ns", "end_ns")
"""Columns that are entry fields; any other column is metadata."""
_FIX = "a CSV manifest is a header row (uri, and optionally task, start_s, end_s, any metadata columns) and one row per bag."


def _header(reader: Any, source: str) -> list[str]:
    header = [name.strip() for name in next(reader, [])]
    if "uri" not in header:
        raise ManifestError(
            f"the header row has no 'uri' column (columns: {', '.join(header) or 'none'})",
            file=source,
            row=1,
            fix=_FIX,
        )
    for index, name in enumerate(header):
        if not name or name in header[:index]:
            what = "an empty column name" if not name else f"column {name!r} twice"
            raise ManifestError(
                f"the header row has {what}", file=source, row=1, column=name or None, fix=_FIX
            )
    return header


def csv_entries(text: str, source: str) -> list[tuple[int, dict[str, Any]]]:
    """``(row number, entry)`` per non-empty data row, each entry in the shape of a YAML manifest entry
    (``metadata`` holds the columns that are not entry fields)."""
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")))
    try:
        header = _header(reader, source)
        entries: list[tuple[int, dict[str, Any]]] = []
        for cells in reader:
            if not any(cell.strip() for cell in cells):
                continue
            if len(cells) > len(header):
                raise ManifestError(
                    f"has {len(cells)} cells, the header names {len(header)} columns",
                    file=source,
                    row=reader.line_num,
                    fix="quote cells that contain commas, or add the missing column to the header.",
                )
            entry: dict[str, Any] = {}
            metadata: dict[str, str] = {}
            for name, cell in zip(header, cells, strict=False):
                if value := cell.strip():
                    (entry if name in CSV_FIELDS else metadata)[name] = value
            entries.append((reader.line_num, {**entry, "metadata": metadata}))
    except csv.Error as err:
        raise ManifestError(f"is not valid CSV: {err}", file=source, row=reader.line_num, fix=_FIX) from err
    if not entries:
        raise ManifestError("has no bag rows under its header", file=source, fix=_FIX)
    return entries
