"""One read of a small bag for both passes of an episode.

Pass 1 (:func:`~bagport.episode.timeline.scan_timeline`) reads every message of the contract's topics
for their stamps; pass 2 (:func:`~bagport.episode.assemble.iter_frames`) reads them again to decode
the selected ones. For a small bag the second read costs as much as the first (the storage plugin
parses every record in Python) while the messages fit in a few megabytes, so :class:`ReplayReader`
keeps the messages of each *complete* read and serves a later read they cover from memory, in the
same order. A read that ends early is not kept; one over the budget stops being kept, and the later
read goes to the bag as before: memory is bounded by the budget, whatever the bag's length.

What a kept read gives is what the bag gave: the reader checked it (damage, counts against the
index) when it was read; the deserialised message a pass asked for is shared by the later pass.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from bagport.bags import BagMessage, BagReader
from bagport.bags.view import ReaderView
from bagport.msgtypes import global_topic

__all__ = ["REPLAY_MAX_BYTES", "REPLAY_MAX_MESSAGES", "ReplayReader", "replayable"]

REPLAY_MAX_BYTES = 16 * 2**20
"""Message bytes one episode keeps in memory at most (a bag larger than this is read twice)."""
REPLAY_MAX_MESSAGES = 50_000
"""Messages kept at most (each costs a small Python object beside its bytes)."""


@dataclass(frozen=True, slots=True)
class _Read:
    """The messages one complete read gave, and what it asked for (``None``: no bound)."""

    topics: frozenset[str] | None
    start_ns: int | None
    stop_ns: int | None
    messages: list[BagMessage]

    def covers(self, topics: frozenset[str] | None, start_ns: int | None, stop_ns: int | None) -> bool:
        """Whether this read holds every message the asked read gives: its topics and its window."""
        holds_topics = self.topics is None or (topics is not None and topics <= self.topics)
        return (
            holds_topics
            and (self.start_ns is None or (start_ns is not None and start_ns >= self.start_ns))
            and (self.stop_ns is None or (stop_ns is not None and stop_ns <= self.stop_ns))
        )

    def replay(
        self, topics: frozenset[str] | None, start_ns: int | None, stop_ns: int | None
    ) -> Iterator[BagMessage]:
        low = -(2**63) if start_ns is None else start_ns
        high = 2**63 if stop_ns is None else stop_ns
        for message in self.messages:
            if (topics is None or message.topic in topics) and low <= message.log_time_ns < high:
                yield message


class ReplayReader(ReaderView):
    """A :class:`~bagport.bags.BagReader` over an open bag (its owner closes it) that serves a read
    covered by an earlier complete read (the same or fewer topics, a window inside) from memory."""

    def __init__(
        self, reader: BagReader, max_bytes: int = REPLAY_MAX_BYTES, max_messages: int = REPLAY_MAX_MESSAGES
    ) -> None:
        super().__init__(reader)
        self._bytes_left = max_bytes
        self._messages_left = max_messages
        self._reads: list[_Read] = []

    @property
    def replays(self) -> int:
        """Complete reads kept so far."""
        return len(self._reads)

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        wanted = None if topics is None else frozenset(global_topic(t) for t in topics)
        for read in self._reads:
            if read.covers(wanted, start_ns, stop_ns):
                return read.replay(wanted, start_ns, stop_ns)
        return self._keep(topics, wanted, start_ns, stop_ns)

    def _keep(
        self,
        topics: Sequence[str] | None,
        wanted: frozenset[str] | None,
        start_ns: int | None,
        stop_ns: int | None,
    ) -> Iterator[BagMessage]:
        kept: list[BagMessage] | None = []
        size = count = 0
        for message in self._reader.messages(topics, start_ns=start_ns, stop_ns=stop_ns):
            if kept is not None:
                size, count = size + message.raw_size, count + 1
                if size > self._bytes_left or count > self._messages_left:
                    kept = None  # over the budget: this read is not kept
                else:
                    kept.append(message)
            yield message
        if kept is not None:  # the read completed: the reader checked its counts
            self._bytes_left, self._messages_left = self._bytes_left - size, self._messages_left - count
            self._reads.append(_Read(wanted, start_ns, stop_ns, kept))

    def close(self) -> None:
        """Forget the kept reads (the bag itself stays open: its owner closes it)."""
        self._reads.clear()


def replayable(reader: BagReader) -> BagReader:
    """``reader`` wrapped in a :class:`ReplayReader` when its bag is small enough to keep (its file size
    and message count within the budget); else ``reader`` itself, read once per pass."""
    info = reader.info
    if info.size_bytes <= REPLAY_MAX_BYTES and info.message_count <= REPLAY_MAX_MESSAGES:
        return ReplayReader(reader)
    return reader
