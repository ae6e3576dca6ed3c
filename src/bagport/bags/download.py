"""A remote bag copied to local scratch, for the storages that cannot be read in place (SQLite, ROS 1)."""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fsspec.core import url_to_fs

from bagport.errors import BagReadError, TransientError
from bagport.scratch import scratch_dir
from bagport.uris import is_local

__all__ = ["download_bag"]


def download_bag(uri: str, storage_options: Mapping[str, Any]) -> tuple[Path, Path | None]:
    """The bag's local path, and the folder to remove after reading it (``None`` for a local bag): a remote
    bag that cannot be read in place (ranged reads: MCAP only) is copied to a private scratch folder first."""
    try:
        fs, path = url_to_fs(uri, **storage_options)
    except (ValueError, ImportError) as err:
        raise BagReadError(f"cannot be opened ({err})", uri=uri, fix="check the URI scheme.") from err
    if is_local(fs):
        return Path(path), None
    scratch = scratch_dir("bag")
    local = scratch / path.rstrip("/").rsplit("/", 1)[-1]
    try:
        if fs.isdir(path):
            local.mkdir()
            for remote in fs.find(path):
                target = local / remote[len(path.rstrip("/")) + 1 :]
                target.parent.mkdir(parents=True, exist_ok=True)
                fs.get_file(remote, str(target))
        else:
            fs.get_file(path, str(local))
    except FileNotFoundError as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise BagReadError("does not exist", uri=uri, fix="check the manifest uri.") from err
    except PermissionError as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise BagReadError(
            f"access denied ({err})", uri=uri, fix="check the credentials for this store."
        ) from err
    except (ConnectionError, TimeoutError, OSError) as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise TransientError(f"{uri}: download failed ({type(err).__name__}: {err}); try again") from err
    return local, scratch
