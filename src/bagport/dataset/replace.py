"""Writing an output whole: refuse one that exists (unless replacing it), build the new one, and put it in
place with the publish guarantees: locally built beside the target and exchanged atomically
(:mod:`bagport.dataset.publish`), on an object store built locally and uploaded under the intent record
(:mod:`bagport.dataset.remote`). The LeRobot writer and the other formats (:mod:`bagport.formats`) share it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.dataset.layout import INFO_PATH
from bagport.dataset.publish import building_beside, swap_into_place
from bagport.dataset.remote import publish_remote
from bagport.errors import DatasetWriteError, OutputInBagError
from bagport.scratch import scratch_folder
from bagport.uris import is_local

__all__ = ["publish_built", "refuse_existing", "refuse_output_in_a_bag"]


def refuse_existing(output: str, *, overwrite: bool, inputs: Sequence[str] = ()) -> None:
    """An existing ``output`` is an error unless ``overwrite`` (call after repairing it), and even then
    unless it is a dataset (its ``meta/info.json``, which every output bagport writes has) or an empty
    folder, and holds none of the run's ``inputs`` (bag URIs): replacing an output removes what it held.
    """
    fs, out_path = url_to_fs(output)
    if not fs.exists(out_path):
        return
    if not overwrite:
        raise DatasetWriteError(
            f"{output} already exists; nothing was written. Fix: choose a new --output, pass --overwrite to "
            "replace it (the old one is kept until the new one is complete), or --append to add the manifest's "
            "new bags to a LeRobot dataset there."
        )
    if not _a_dataset_or_empty(fs, out_path):
        raise DatasetWriteError(
            f"{output} exists and is not a dataset (no meta/info.json): --overwrite replaces only a dataset "
            f"(or an empty folder), as it removes everything the output holds; nothing was written. Fix: "
            f"choose a new --output, or move {output} away yourself if it is meant to go."
        )
    root = _real(fs, out_path).rstrip("/") + "/"
    for uri in inputs:
        bag_fs, bag_path = url_to_fs(uri)
        if bag_fs.protocol == fs.protocol and _real(bag_fs, bag_path).startswith(root):
            raise DatasetWriteError(
                f"{output} holds the bag {uri}, and --overwrite would remove it with the old dataset; "
                "nothing was written. Fix: keep the bags outside the dataset's folder, or write to a new "
                "--output."
            )


def refuse_output_in_a_bag(output: str, inputs: Sequence[str], what: str = "--output") -> None:
    """The converse of :func:`refuse_existing`'s check: an ``output`` that is, or is inside, one of the run's
    ``inputs`` (a rosbag2 folder) would put the dataset (and its temporary folders) into a recording; so
    would a staging store there (``what``: ``--staging``) put the staged episodes."""
    fs, out_path = url_to_fs(output)
    out_real = _real(fs, out_path).rstrip("/")
    for uri in inputs:
        bag_fs, bag_path = url_to_fs(uri)
        bag_real = _real(bag_fs, bag_path).rstrip("/")
        if bag_fs.protocol == fs.protocol and (out_real == bag_real or out_real.startswith(bag_real + "/")):
            raise OutputInBagError(option=what, path=output, bag_uri=uri)


def _real(fs: AbstractFileSystem, path: str) -> str:
    """A local path with its links and ``..`` resolved (``../ds`` and a link to it name one folder); an
    object store's key as it is."""
    return os.path.realpath(path) if is_local(fs) else path


def _a_dataset_or_empty(fs: AbstractFileSystem, path: str) -> bool:
    if fs.isfile(path):
        return False
    return bool(fs.exists(f"{path.rstrip('/')}/{INFO_PATH}")) or not fs.ls(path, detail=False)


def publish_built[Report](output: str, build: Callable[[Path], Report], *, overwrite: bool) -> Report:
    """``build(root)`` writes the output's files under a fresh local ``root``; they replace ``output``
    whole (stale files of a replaced remote output removed), or nothing changes there."""
    fs, out_path = url_to_fs(output)
    if is_local(fs):
        final = Path(out_path)
        with building_beside(final) as root:
            report = build(root)
            swap_into_place(root, final, overwrite=overwrite)
        return report
    with scratch_folder("output") as scratch:
        root = scratch / "output"
        root.mkdir()
        report = build(root)
        files = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
        existing = (
            {p[len(out_path.rstrip("/")) + 1 :] for p in fs.find(out_path)} if fs.exists(out_path) else set()
        )
        publish_remote(root, output, files, sorted(existing - set(files)), overwrite=overwrite)
    return report
