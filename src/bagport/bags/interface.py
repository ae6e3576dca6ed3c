"""What every bag reader offers: :class:`BagReader` (rosbags' readers, a time window of one, a replay of a
first pass), so the modules that wrap or consume a reader need not import the one that opens bags."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import TracebackType
from typing import Protocol

from bagport.bags.message import BagMessage
from bagport.bags.publish import Int64Array
from bagport.bags.records import BagInfo
from bagport.bags.remote import TransferStats

__all__ = ["BagReader"]


class BagReader(Protocol):
    @property
    def info(self) -> BagInfo: ...

    @property
    def transfer(self) -> TransferStats: ...

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        """Messages in log-time order; only those logged in ``[start_ns, stop_ns)`` when given."""
        ...

    def publish_times_ns(self, topics: Sequence[str]) -> dict[str, tuple[Int64Array, Int64Array]]: ...

    def close(self) -> None: ...

    @property
    def undefined_types(self) -> dict[str, str]:
        """``{topic: msgtype}`` of topics whose type no source defines (reading them fails)."""
        ...

    def __enter__(self) -> BagReader: ...

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None: ...
