"""A cheap stamp of a bag's files (names, sizes, modification times) from fsspec metadata alone."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from typing import Any

from fsspec.core import url_to_fs

__all__ = ["source_stamp"]

_CHANGE_KEYS = ("size", "mtime", "LastModified", "ETag", "created")


def source_stamp(uri: str, *, storage_options: Mapping[str, Any] | None = None) -> str:
    """Changes when any file of the bag is replaced, grows or shrinks; no payload is read.

    Returns ``""`` when the bag cannot be listed (the caller then converts it afresh).
    """
    try:
        fs, path = url_to_fs(uri, **dict(storage_options or {}))
        files = fs.find(path, detail=True) if fs.isdir(path) else {path: fs.info(path)}
    except (OSError, ValueError):
        return ""
    digest = hashlib.sha256()
    for name in sorted(files):
        info = files[name]
        digest.update(name[len(path) :].encode())
        for key in _CHANGE_KEYS:
            digest.update(f"{key}={info.get(key)!s};".encode())
    return "files:" + digest.hexdigest()[:32]
