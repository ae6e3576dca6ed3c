"""What kind of store an fsspec filesystem is."""

from __future__ import annotations

from fsspec import AbstractFileSystem

__all__ = ["is_local", "protocol_of"]


def protocol_of(fs: AbstractFileSystem) -> str:
    """The filesystem's main protocol name (``file``, ``s3``, ``memory`` ...)."""
    protocol = fs.protocol
    return str(protocol[0] if isinstance(protocol, tuple) else protocol)


def is_local(fs: AbstractFileSystem) -> bool:
    """True for the local disk, where paths can be opened directly and renamed atomically."""
    names = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "file" in names or "local" in names
