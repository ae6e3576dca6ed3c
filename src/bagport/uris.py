"""What kind of store an fsspec filesystem is, and reading small files from any of them."""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import fsspec
from fsspec import AbstractFileSystem
from fsspec.core import url_to_fs

from bagport.errors import ContractError, DatasetWriteError, ManifestError

__all__ = [
    "UTF8_FIX",
    "is_local",
    "output_fs",
    "protocol_of",
    "read_text",
    "read_text_file",
    "require_bucket",
]

BUCKET_STORES = frozenset({"s3", "s3a", "gs", "gcs", "abfs", "abfss", "az", "adl"})
"""Object stores whose first path component is a bucket (container) that writing would create."""


def protocol_of(fs: AbstractFileSystem) -> str:
    """The filesystem's main protocol name (``file``, ``s3``, ``memory`` ...)."""
    protocol = fs.protocol
    return str(protocol[0] if isinstance(protocol, tuple) else protocol)


def is_local(fs: AbstractFileSystem) -> bool:
    """True for the local disk, where paths can be opened directly and renamed atomically."""
    names = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "file" in names or "local" in names


UTF8_FIX = "save it as UTF-8 (from Latin-1: `iconv -f latin1 -t utf-8 OLD > NEW`)."


def read_text_file(
    uri: str,
    *,
    error: type[ContractError] | type[ManifestError],
    subject: str,
    fix: str,
    missing_fix: str | None = None,
    storage_options: Mapping[str, Any] | None = None,
) -> str:
    """A small UTF-8 text file from a local path or any fsspec URI. One that is missing, not UTF-8 or cannot
    be read is an ``error`` at ``uri`` that calls it ``subject`` (``contract file``), with ``fix`` (or
    ``missing_fix`` when it does not exist)."""
    try:
        with fsspec.open(uri, "r", encoding="utf-8", **(storage_options or {})) as handle:
            return str(handle.read())
    except FileNotFoundError as err:
        raise error(f"{subject} does not exist", file=uri, fix=missing_fix or fix) from err
    except UnicodeDecodeError as err:
        raise error(
            f"{subject} is not UTF-8 text (the byte at offset {err.start} is not)", file=uri, fix=UTF8_FIX
        ) from err
    except (ValueError, ImportError) as err:  # (UnicodeDecodeError is a ValueError: caught above)
        raise error(
            f"{subject} cannot be opened: fsspec does not know its protocol ({err})",
            file=uri,
            fix="give a local path, or a URI fsspec knows (s3://, gs://, ...) with its package installed "
            "(s3fs, gcsfs, ...).",
        ) from err
    except OSError as err:
        raise error(f"{subject} cannot be read ({err.strerror or err})", file=uri, fix=fix) from err


def read_text(uri: str, what: str) -> str:
    """A run's small text file (contract, QA thresholds), given as ``--{what}`` or ``{what}:`` in a
    ``--config`` file: :func:`read_text_file` raising :class:`ContractError`."""
    check = f"check the path given as --{what} (or {what}: in a --config file)"
    return read_text_file(
        uri,
        error=ContractError,
        subject=f"{what} file",
        fix=f"{check}.",
        missing_fix=f"{check}; a relative path is relative to the working directory.",
    )


def output_fs(uri: str, what: str) -> tuple[AbstractFileSystem, str]:
    """fsspec's file system and path for an output or staging ``uri`` (``what``: its option); a protocol
    fsspec does not know (a typo, or its package not installed), or a local path that is a file or lies
    under one, is one paragraph."""
    if not uri.strip():
        raise DatasetWriteError(
            f"{what} is empty; nothing was converted or written. Fix: give the dataset's folder or URI."
        )
    try:
        fs, path = url_to_fs(uri)
    except (ValueError, ImportError) as err:
        raise DatasetWriteError(
            f"{what} {uri}: fsspec cannot open it ({err}); nothing was converted or written. Fix: a local "
            "path, or a URI fsspec knows (s3://, gs://, ...) with its package installed (s3fs, gcsfs, ...)."
        ) from err
    if is_local(fs):
        _nearest_folder(Path(str(path)), uri, what)
    return fs, str(path)


def check_writable(fs: AbstractFileSystem, path: str, uri: str, what: str, *, beside: bool = False) -> None:
    """A local ``path`` (of :func:`output_fs`) this user cannot write is one paragraph: a temporary file is
    opened where the run will write (the nearest folder of ``path`` that exists; with ``beside``, also its
    parent's, where a dataset's build folder goes). Object stores are not checked here."""
    if not is_local(fs):
        return
    local = Path(path)
    for folder in (local, local.parent) if beside else (local,):
        _check_local_folder(folder, uri, what)


def _nearest_folder(path: Path, uri: str, what: str) -> Path | None:
    """The nearest of ``path`` and its parents that exists (``None``: none does); a file there, where every
    episode would fail to stage with a bare ``NotADirectoryError``, is said once, before anything converts."""
    folder = next((f for f in (path, *path.parents) if f.exists()), None)
    if folder is not None and not folder.is_dir():
        where = "is a file" if folder == path else f"lies under {folder}, which is a file"
        raise DatasetWriteError(
            f"{what} {uri} {where}; nothing was converted or written. Fix: give a folder path (one that "
            "does not exist yet is made)."
        )
    return folder


def _check_local_folder(path: Path, uri: str, what: str) -> None:
    """The nearest folder of ``path`` must take a new file: one this user cannot write (permissions, a
    read-only mount, /proc) failed every episode with a bare ``PermissionError``; said once, before anything
    converts."""
    folder = _nearest_folder(path, uri, what)
    if folder is None:
        return
    try:  # an unnamed file where the OS has them (O_TMPFILE): nothing to remove, nothing left if killed
        with tempfile.TemporaryFile(prefix=".bagport-write-check-", dir=folder):
            pass
    except OSError as err:
        raise DatasetWriteError(
            f"{what} {uri}: nothing can be written in {folder} ({err.strerror or err}); nothing was converted "
            "or written. Fix: give a folder this user can write (check its owner and permissions, the free "
            "space, and whether it is mounted read-only)."
        ) from err


def require_bucket(fs: AbstractFileSystem, path: str, uri: str) -> None:
    """An object-store ``uri`` must name a bucket that exists: writing into a misspelt bucket would
    create a new one (s3fs does) and hide the dataset there. Other stores pass unchecked."""
    if protocol_of(fs) not in BUCKET_STORES:
        return
    bucket = path.strip("/").split("/", 1)[0]
    if bucket and fs.exists(bucket):
        return
    raise DatasetWriteError(
        f"{uri}: the bucket {bucket!r} does not exist (or these credentials cannot see it); nothing was "
        "converted or written. Fix: check the bucket name in --output/--staging, or create the bucket "
        "first (bagport never creates buckets)."
    )
