"""What a process-pool worker needs before its first task, done once in the forkserver
(:mod:`flows.forkserver`) so that every worker forked from it starts with it done: Prefect's task
engine and runners, bagport's tasks (and through them the library), the flow's own module, the modules
libraries import lazily at a worker's first task run and episode, and Prefect's collections.

A worker unpickles the flow with the flow run's context, which imports :mod:`flows.convert` (and with
it the reduce's flow modules): 0.2 s in each worker before its first episode, when it was not here.

Prefect loads every installed collection (the ``prefect.collections`` entry points) the first time a
process turns a block's data into a block, which a worker does when it rebuilds the flow's context
(its result storage); ``prefect-dask`` imports Dask's ``distributed`` then.
"""

from __future__ import annotations

from flows.import_gc import paused

with paused():  # frozen after: the forked workers' collections skip them (flows/import_gc.py)
    # Prefect's task engine and runners, bagport's tasks, the flow's module, and what a worker imported
    # late, in its first task run or episode (anyio's asyncio backend for Prefect's async clients,
    # pyarrow's pandas glue, PyAV's subtitles, rosbags' primitives: 15 modules, 40-60 ms of its start)
    import anyio._backends._asyncio
    import av.subtitles.stream
    import prefect.task_engine
    import prefect.task_runners
    import pyarrow.pandas_compat
    import rosbags.serde.primitives
    from prefect.plugins import load_prefect_collections

    import flows.convert
    import tasks.episode
    import tasks.segment
    from bagport.bags import prepare_reading

    _COLLECTIONS = load_prefect_collections()
    prepare_reading()  # rosbags' type stores: built once here, not in each worker's first episode

__all__ = ["PRELOADED"]

PRELOADED = (
    anyio._backends._asyncio,
    av.subtitles.stream,
    pyarrow.pandas_compat,
    rosbags.serde.primitives,
    flows.convert,
    prefect.task_engine,
    prefect.task_runners,
    tasks.episode,
    tasks.segment,
    _COLLECTIONS,
)
"""The modules (and collections) imported here; named so the imports are not unused."""
