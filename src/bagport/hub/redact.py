"""What of a dataset's provenance and QA record is published: everything, a redacted copy, or none.

Provenance (``meta/provenance/``) and the QA record (``meta/qa/``) name the bags by their full local or
S3 paths, and ``run.json`` carries the manifest's operator metadata. The redacted copy reduces every bag,
manifest and contract path to its last part (``s3://fleet/2026-05/ep7.mcap`` -> ``ep7.mcap``), in JSON,
HTML and parquet alike (parquet streamed by batches), and drops the episodes' manifest ``metadata``; every
redacted file is then searched for the original paths, and the push is refused if one is left.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Literal

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from bagport.errors import PushError

__all__ = ["PROVENANCE_CHOICES", "ProvenanceChoice", "publish_view"]

ProvenanceChoice = Literal["full", "redacted", "excluded"]
PROVENANCE_CHOICES: tuple[ProvenanceChoice, ...] = ("full", "redacted", "excluded")
_PRIVATE = ("meta/provenance/", "meta/qa/")
_SKIPPED = ("images/",)  # LeRobot's push_to_hub leaves out images/ too


def _name(path: str) -> str:
    return path.rstrip("/").rsplit("/", 1)[-1] or path


def recorded_paths(root: Path) -> list[str]:
    """Every bag, manifest and contract path the dataset's run records and QA summary name, longest first."""
    paths: set[str] = set()
    for record in sorted((root / "meta/provenance").glob("run*.json")):
        run = json.loads(record.read_text())
        paths.update(
            str(p) for p in (run.get("contract", {}).get("uri"), run.get("manifest", {}).get("uri")) if p
        )
        paths.update(str(p) for p in run.get("manifest", {}).get("bags", []))
        paths.update(str(p) for p in run.get("manifest", {}).get("converted_now", []))
        paths.update(str(e["bag_uri"]) for e in [*run.get("episodes", []), *run.get("excluded", [])])
    summary = root / "meta/qa/summary.json"
    if summary.is_file():
        for row in _rows(json.loads(summary.read_text())):
            if isinstance(row, dict) and row.get("bag_uri"):
                paths.add(str(row["bag_uri"]))
    # the QA report groups bags by folder (its breakdown by bag prefix), and names the dataset itself
    paths.update(p.rstrip("/").rsplit("/", 1)[0] for p in list(paths) if "/" in p.rstrip("/"))
    paths.add(str(root))
    return sorted((p for p in paths if "/" in p and p.strip("/")), key=len, reverse=True)


def _rows(data: Any) -> list[Any]:
    if isinstance(data, list):
        return data
    if isinstance(data, dict):
        return [v for value in data.values() for v in (value if isinstance(value, list) else [value])]
    return []


def _redact_text(text: str, paths: list[str]) -> str:
    for path in paths:
        text = text.replace(path, _name(path))
    return text


def _redact_json(data: Any, paths: list[str]) -> Any:
    if isinstance(data, str):
        return _redact_text(data, paths)
    if isinstance(data, list):
        return [_redact_json(v, paths) for v in data]
    if isinstance(data, dict):
        return {k: _redact_json(v, paths) for k, v in data.items() if k != "metadata"}
    return data


def _redact_parquet(source: Path, target: Path, paths: list[str]) -> None:
    """Row group by row group (a provenance table has a row per frame and source)."""
    reader = pq.ParquetFile(source)
    writer: pq.ParquetWriter | None = None
    try:
        for batch in reader.iter_batches():
            columns = []
            for field, column in zip(batch.schema, batch.columns, strict=True):
                kind = field.type.value_type if pa.types.is_dictionary(field.type) else field.type
                if pa.types.is_string(kind) or pa.types.is_large_string(kind):
                    redacted: Any = column.cast(kind)
                    for path in paths:
                        redacted = pc.replace_substring(redacted, pattern=path, replacement=_name(path))
                    columns.append(redacted.cast(field.type))
                else:
                    columns.append(column)
            table = pa.Table.from_arrays(columns, schema=batch.schema)
            _refuse_leftover_paths(target.name, str(table.to_pylist()).encode(), paths)
            if writer is None:
                writer = pq.ParquetWriter(target, reader.schema_arrow, compression="zstd")
            writer.write_table(table)
    finally:
        if writer is not None:
            writer.close()
    if writer is None:
        pq.write_table(reader.schema_arrow.empty_table(), target)


def _redact_file(source: Path, target: Path, paths: list[str]) -> None:
    if source.suffix == ".json":
        target.write_text(json.dumps(_redact_json(json.loads(source.read_text()), paths), indent=2))
        _refuse_leftover_paths(str(source), target.read_bytes(), paths)
    elif source.suffix == ".parquet":
        _redact_parquet(source, target, paths)
    else:
        target.write_text(_redact_text(source.read_text(encoding="utf-8"), paths), encoding="utf-8")
        _refuse_leftover_paths(str(source), target.read_bytes(), paths)


def _link(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def publish_view(root: Path, view: Path, provenance: ProvenanceChoice) -> list[str]:
    """Fill ``view`` with what is published of the dataset at ``root`` (data and videos hard-linked,
    not copied); the published files, relative."""
    paths = recorded_paths(root)
    published = []
    for source in sorted(p for p in root.rglob("*") if p.is_file()):
        rel = source.relative_to(root).as_posix()
        if (
            rel.startswith(_SKIPPED)
            or rel.startswith(".")
            or (provenance == "excluded" and rel.startswith("meta/provenance/"))
        ):
            continue
        target = view / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if provenance != "full" and rel.startswith(_PRIVATE):
            _redact_file(source, target, paths)
        else:
            _link(source, target)
        published.append(rel)
    return published


def _refuse_leftover_paths(where: str, content: bytes, paths: list[str]) -> None:
    for path in paths:
        if _name(path) != path and path.encode() in content:
            raise PushError(
                f"{where} still names {path} after redaction; nothing was pushed. Fix: push with "
                "--exclude-provenance, or report this as a bagport bug."
            )
