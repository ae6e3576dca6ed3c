"""A run that outlives its console: output to a closed pipe is dropped, the conversion goes on.

``bagport convert ... | head``, a ``tee`` or a log shipper that dies, a pager closed early: the reader
of the program's stdout or stderr goes away while the run works. Python then raises ``BrokenPipeError``
at the next write, and Prefect's console handler (rich) turns that into ``SystemExit(1)`` in whichever
thread logged: the flow ended with exit code 1 and no dataset, or a task run in a pool worker crashed and
the flow waited for it forever. The console is only a view of the run (its logs are on the Prefect
server, its record in the dataset), so losing it must not lose the run: once a stream's pipe is closed,
its file descriptor is pointed at ``/dev/null`` and what is written is dropped. Standard library only
(installed before Prefect is imported, so Prefect's handlers take these streams).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any, TextIO

__all__ = ["outlive_closed_output"]


class _ClosedPipeTolerant:
    """``stream``, except that writing to a closed pipe drops the text instead of raising."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._to_devnull()
            return len(text)

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._to_devnull()

    def _to_devnull(self) -> None:
        """Point the stream's descriptor at /dev/null: its buffered text and all later text go nowhere."""
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)
        with contextlib.suppress(OSError):
            self._stream.flush()  # the text left in its buffer, now to /dev/null

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def outlive_closed_output() -> None:
    """Make this process's stdout and stderr drop what they cannot write to a closed pipe (module docs).

    Called by the ``bagport`` program before anything else; forked workers inherit it."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is not None and not isinstance(stream, _ClosedPipeTolerant):
            setattr(sys, name, _ClosedPipeTolerant(stream))
