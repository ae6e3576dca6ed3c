"""A bag seen through a time window: one episode of several recorded in one bag."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import TracebackType

from bagport.bags.message import BagMessage
from bagport.bags.reader import BagReader
from bagport.bags.records import BagInfo

__all__ = ["BagWindow"]


class BagWindow:
    """``BagReader`` over the messages of ``reader`` logged in ``[start_ns, end_ns]``.

    Closing the view leaves ``reader`` open: its owner closes it.
    """

    def __init__(self, reader: BagReader, start_ns: int, end_ns: int) -> None:
        self._reader = reader
        self.start_ns = start_ns
        self.end_ns = end_ns

    @property
    def info(self) -> BagInfo:
        return self._reader.info

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        start = self.start_ns if start_ns is None else max(start_ns, self.start_ns)
        stop = self.end_ns + 1 if stop_ns is None else min(stop_ns, self.end_ns + 1)
        return self._reader.messages(topics, start_ns=start, stop_ns=stop)

    def close(self) -> None:
        return None

    def __enter__(self) -> BagWindow:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
