"""What kind of store an fsspec filesystem is, and reading small files from any of them."""

from __future__ import annotations

import fsspec
from fsspec import AbstractFileSystem

from bagport.errors import ContractError

__all__ = ["is_local", "protocol_of", "read_text"]


def protocol_of(fs: AbstractFileSystem) -> str:
    """The filesystem's main protocol name (``file``, ``s3``, ``memory`` ...)."""
    protocol = fs.protocol
    return str(protocol[0] if isinstance(protocol, tuple) else protocol)


def is_local(fs: AbstractFileSystem) -> bool:
    """True for the local disk, where paths can be opened directly and renamed atomically."""
    names = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "file" in names or "local" in names


def read_text(uri: str, what: str) -> str:
    """A small text file (contract, QA thresholds) from a local path or any fsspec URI."""
    try:
        with fsspec.open(uri, "r", encoding="utf-8") as handle:
            return str(handle.read())
    except FileNotFoundError as err:
        raise ContractError(f"{what} file does not exist", file=uri, fix=f"check the --{what} path.") from err
