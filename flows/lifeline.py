"""A lifeline: the read end of a pipe whose write end only the process that started this one holds.

Nothing is ever written to it; a read returns at its end, which comes when that process closes its end,
exits or is killed (SIGKILL, the OOM killer) without stopping what it started. bagport's temporary
Prefect server and the local pool's forked workers each watch one, so a killed run leaves nothing
running. Standard library only (the server imports it before Prefect's app).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection

__all__ = ["when_cut"]


def when_cut(lifeline: Connection, then: Callable[[], None]) -> None:
    """Call ``then`` on a daemon thread once ``lifeline``'s other end is closed (or it cannot be read)."""

    def watch() -> None:
        with contextlib.suppress(EOFError, OSError):  # EOFError: the other end closed
            lifeline.recv_bytes()
        then()

    threading.Thread(target=watch, name="bagport-lifeline", daemon=True).start()
