"""Writing an output whole: refuse one that exists (unless replacing it), build the new one, and put it in
place with the publish guarantees: locally built beside the target and exchanged atomically
(:mod:`bagport.dataset.publish`), on an object store built locally and uploaded under the intent record
(:mod:`bagport.dataset.remote`). The LeRobot writer and the other formats (:mod:`bagport.formats`) share it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fsspec.core import url_to_fs

from bagport.dataset.publish import building_beside, swap_into_place
from bagport.dataset.remote import publish_remote
from bagport.errors import DatasetWriteError
from bagport.scratch import scratch_folder
from bagport.uris import is_local

__all__ = ["publish_built", "refuse_existing"]


def refuse_existing(output: str, *, overwrite: bool) -> None:
    """An existing ``output`` is an error unless ``overwrite`` (call after repairing it)."""
    fs, out_path = url_to_fs(output)
    if fs.exists(out_path) and not overwrite:
        raise DatasetWriteError(
            f"{output} already exists; nothing was written. Fix: choose a new --output, or pass --overwrite "
            "to replace it (the old one is kept until the new one is complete)."
        )


def publish_built[Report](output: str, build: Callable[[Path], Report]) -> Report:
    """``build(root)`` writes the output's files under a fresh local ``root``; they replace ``output``
    whole (stale files of a replaced remote output removed), or nothing changes there."""
    fs, out_path = url_to_fs(output)
    if is_local(fs):
        final = Path(out_path)
        with building_beside(final) as root:
            report = build(root)
            swap_into_place(root, final)
        return report
    with scratch_folder("output") as scratch:
        root = scratch / "output"
        root.mkdir()
        report = build(root)
        files = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
        existing = (
            {p[len(out_path.rstrip("/")) + 1 :] for p in fs.find(out_path)} if fs.exists(out_path) else set()
        )
        publish_remote(root, output, files, sorted(existing - set(files)))
    return report
