"""Heavy imports with Python's cyclic garbage collector paused.

Importing Prefect (its server, its client, their pydantic models) and the library allocates hundreds of
thousands of objects that live as long as the process. While they pile up, the collector runs again
and again over all of them and finds next to nothing to free. Paused through the imports, with the
survivors frozen after them (``gc.freeze``: later collections skip them, and a forked worker does not
touch their pages; CPython's docs advise it before forking), the temporary server's import took 2.0-2.1 s
instead of 2.6-3.0 s, and the CLI's and the pool workers' about 0.2 s less each (2 cores).

The collector is paused only while modules are imported; episodes are converted with it running.
Standard library only.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["SERVER_PREAMBLE", "paused", "resume"]

SERVER_PREAMBLE = "import gc; gc.disable()"
"""The temporary server's first statement (its command line), before uvicorn imports the app, which
calls :func:`resume` once it is built (:mod:`flows.local_server_app`)."""


def resume() -> None:
    """Freeze what was imported (later collections skip it), then let the collector run again."""
    gc.freeze()
    gc.enable()


@contextmanager
def paused() -> Iterator[None]:
    """The collector off in the block (imports), then :func:`resume`; off again after if it was off."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            resume()
        else:
            gc.freeze()
