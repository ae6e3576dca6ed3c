"""Recovery of a dataset a killed run left mid-write: before any run touches it, and ``bagport repair``.

Local outputs go through :func:`bagport.dataset.publish.recover_local`, object stores through
:func:`bagport.dataset.remote.recover_remote`; both roll the interrupted write forward or back
from its intent record (:mod:`bagport.dataset.journal`) to one consistent dataset.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pyarrow.parquet as pq
from fsspec.core import url_to_fs

from bagport.dataset.layout import INFO_PATH, JOURNAL_PATH
from bagport.dataset.publish import recover_local
from bagport.dataset.remote import recover_remote
from bagport.scratch import clean_dead_scratch
from bagport.uris import is_local

__all__ = ["RepairReport", "interrupted_write", "repair_dataset"]


@dataclass(frozen=True, slots=True)
class RepairReport:
    output: str
    actions: tuple[str, ...]
    """What was done, one sentence each (empty: the dataset was consistent)."""


def _unreferenced_tail(root: Path) -> list[Path]:
    """Data and video files after the last ones ``meta/episodes`` refers to: what an append of a bagport
    without the intent record moved in before it was killed (LeRobot would read their rows)."""
    if not (root / INFO_PATH).is_file() or not (root / "meta/episodes").is_dir():
        return []
    files = sorted((root / "meta/episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        return []
    newest = pq.ParquetFile(files[-1])  # the last data/video files are the last episodes' (rows go in order)
    where = [c for c in newest.schema_arrow.names if c.endswith(("/chunk_index", "/file_index"))]
    episodes = newest.read_row_group(newest.num_row_groups - 1, columns=where).to_pandas()
    tails = []
    for column in [c[: -len("/chunk_index")] for c in episodes.columns if c.endswith("/chunk_index")]:
        if column == "meta/episodes":
            continue
        last = max(zip(episodes[f"{column}/chunk_index"], episodes[f"{column}/file_index"], strict=True))
        folder = root / column
        for path in sorted(folder.glob("chunk-*/file-*.*")):
            chunk, file = (int(part.split("-")[1].split(".")[0]) for part in path.parts[-2:])
            if (chunk, file) > last:
                tails.append(path)
    return tails


def _remove_unreferenced(root: Path) -> list[str]:
    tails = _unreferenced_tail(root)
    for path in tails:
        path.unlink()
    return [
        f"removed {p.relative_to(root)}, moved in by an append that was killed before its meta/"
        for p in tails
    ]


def repair_dataset(output: str, *, clean_scratch: bool = False) -> RepairReport:
    """Finish or undo whatever write into ``output`` a crash interrupted; with ``clean_scratch``, also
    remove the temporary folders of dead bagport processes."""
    fs, path = url_to_fs(output)
    actions = recover_local(Path(path)) if is_local(fs) else recover_remote(output)
    if is_local(fs):
        actions += _remove_unreferenced(Path(path))
    if clean_scratch:
        actions += [f"removed {p}, a temporary folder of a dead run" for p in clean_dead_scratch()]
    return RepairReport(output, tuple(actions))


def interrupted_write(root: Path) -> str | None:
    """Why the local dataset folder ``root`` is mid-write (needs repair), or ``None``."""
    if (root / JOURNAL_PATH).is_file():
        return f"{root / JOURNAL_PATH} is present: a write into it did not finish"
    if not (root / INFO_PATH).is_file() and list(root.parent.glob(f".{root.name}.old-*")):
        return f"{root} is missing while a replaced version waits beside it: a replace did not finish"
    if list(root.glob(".meta.old-*")):
        return f"{root} has a .meta.old-* folder: an append did not finish"
    return None
