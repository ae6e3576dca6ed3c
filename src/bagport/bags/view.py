"""A reader over another open reader: the base of the views that change what a read gives."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import TracebackType
from typing import Self

from bagport.bags.interface import BagReader
from bagport.bags.message import BagMessage
from bagport.bags.publish import Int64Array
from bagport.bags.records import BagInfo
from bagport.bags.remote import TransferStats

__all__ = ["ReaderView"]


class ReaderView:
    """A :class:`~bagport.bags.BagReader` that passes everything to ``reader``, which stays open when the
    view closes (its owner closes it). Subclasses override what they change (``messages``...)."""

    def __init__(self, reader: BagReader) -> None:
        self._reader = reader

    @property
    def info(self) -> BagInfo:
        return self._reader.info

    @property
    def transfer(self) -> TransferStats:
        return self._reader.transfer

    @property
    def undefined_types(self) -> dict[str, str]:
        return self._reader.undefined_types

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        return self._reader.messages(topics, start_ns=start_ns, stop_ns=stop_ns)

    def publish_times_ns(self, topics: Sequence[str]) -> dict[str, tuple[Int64Array, Int64Array]]:
        return self._reader.publish_times_ns(topics)

    def close(self) -> None:
        """Nothing to release: the reader underneath is its owner's to close."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
