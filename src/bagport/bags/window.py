"""A bag seen through a time window: one episode of several recorded in one bag."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from bagport.bags.interface import BagReader
from bagport.bags.message import BagMessage
from bagport.bags.publish import Int64Array
from bagport.bags.view import ReaderView

__all__ = ["BagWindow"]


class BagWindow(ReaderView):
    """``BagReader`` over the messages of ``reader`` logged in ``[start_ns, end_ns]``.

    Closing the view leaves ``reader`` open: its owner closes it.
    """

    def __init__(self, reader: BagReader, start_ns: int, end_ns: int) -> None:
        super().__init__(reader)
        self.start_ns = start_ns
        self.end_ns = end_ns

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        start = self.start_ns if start_ns is None else max(start_ns, self.start_ns)
        stop = self.end_ns + 1 if stop_ns is None else min(stop_ns, self.end_ns + 1)
        return self._reader.messages(topics, start_ns=start, stop_ns=stop)

    def publish_times_ns(self, topics: Sequence[str]) -> dict[str, tuple[Int64Array, Int64Array]]:
        out = {}
        for topic, (log_ns, publish_ns) in self._reader.publish_times_ns(topics).items():
            inside = (log_ns >= self.start_ns) & (log_ns <= self.end_ns)
            out[topic] = (np.asarray(log_ns[inside]), np.asarray(publish_ns[inside]))
        return out
