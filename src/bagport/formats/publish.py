"""Publishing another format's output with the LeRobot writer's guarantees, through its public functions.

Locally the output is built in a locked ``.X.tmp-*`` folder beside ``X`` and swapped into place
(:mod:`bagport.dataset.publish`); on an object store it is built in a local temporary folder and
uploaded under the journal of :mod:`bagport.dataset.remote`. What a crashed write left is undone first
(:func:`bagport.dataset.repair.repair_dataset`). Every output has ``meta/info.json``, the file the
local recovery looks for in a complete previous version, and which the upload writes last.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from fsspec.core import url_to_fs

from bagport.dataset.publish import building_beside, swap_into_place
from bagport.dataset.remote import publish_remote
from bagport.dataset.repair import repair_dataset
from bagport.errors import DatasetWriteError
from bagport.scratch import scratch_dir
from bagport.uris import is_local

__all__ = ["check_output_free", "publish_built"]


def check_output_free(output: str, *, overwrite: bool) -> None:
    """Undo a crashed write into ``output``; refuse an existing output unless ``overwrite``."""
    fs, out_path = url_to_fs(output)
    repair_dataset(output)
    if fs.exists(out_path) and not overwrite:
        raise DatasetWriteError(
            f"{output} already exists; nothing was written. Fix: choose a new --output, or pass --overwrite "
            "to replace it (the old output is kept until the new one is complete)."
        )


def publish_built[Report](output: str, *, overwrite: bool, build: Callable[[Path], Report]) -> Report:
    """``build(root)`` writes the output's files under a fresh local ``root``; they replace ``output``
    whole, or nothing changes there."""
    check_output_free(output, overwrite=overwrite)
    fs, out_path = url_to_fs(output)
    if is_local(fs):
        final = Path(out_path)
        with building_beside(final) as root:
            report = build(root)
            swap_into_place(root, final)
        return report
    root = scratch_dir("output") / "output"
    root.mkdir(parents=True)
    try:
        report = build(root)
        files = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
        existing = (
            {p[len(out_path.rstrip("/")) + 1 :] for p in fs.find(out_path)} if fs.exists(out_path) else set()
        )
        publish_remote(root, output, files, sorted(existing - set(files)))
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)
    return report
