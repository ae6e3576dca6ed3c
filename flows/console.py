"""The program's console: output to a closed pipe is dropped and the run goes on; a SIGTERM says what stands.

``bagport convert ... | head``, a ``tee`` or a log shipper that dies, a pager closed early: the reader
of the program's stdout or stderr goes away while the run works. Python then raises ``BrokenPipeError``
at the next write, and Prefect's console handler (rich) turns that into ``SystemExit(1)`` in whichever
thread logged: the flow ended with exit code 1 and no dataset, or a task run in a pool worker crashed and
the flow waited for it forever. The console is only a view of the run (its logs are on the Prefect
server, its record in the dataset), so losing it must not lose the run: once a stream's pipe is closed,
its file descriptor is pointed at ``/dev/null`` and what is written is dropped. Standard library only
(installed before Prefect is imported, so Prefect's handlers take these streams).

A conversion ended by SIGTERM (a scheduler's time limit, a shutdown) still ends at once, as a kill does
(its server and workers stop with it, ``flows/lifeline.py``; the next run resumes and brings a write it
interrupted back, ``docs/fleet.md``), but first says so in one line: before, the only trace was the exit
status and multiprocessing's warning about leaked semaphores.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from types import FrameType
from typing import Any, TextIO

__all__ = ["TERMINATED", "outlive_closed_output", "say_when_terminated"]

TERMINATED = (
    "bagport convert: terminated (SIGTERM) before the run finished. Its finished episodes stay in the staging "
    "store, and a dataset write it had begun is completed or rolled back by the next run: run the same "
    "command again to resume."
)


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


def say_when_terminated() -> None:
    """On SIGTERM, :data:`TERMINATED` on stderr, then the default end (exit status 143, at once). Only the
    process that installed it speaks; a fork of it (the pool's forkserver and workers) just ends."""
    speaker = os.getpid()

    def on_sigterm(_signum: int, _frame: FrameType | None) -> None:
        if os.getpid() == speaker:
            with contextlib.suppress(Exception):
                sys.stderr.write(TERMINATED + "\n")
                sys.stderr.flush()
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)

    signal.signal(signal.SIGTERM, on_sigterm)
