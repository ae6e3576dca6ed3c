"""A real Dask cluster of worker processes on this machine, standing for a fleet's existing one."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from distributed import Client, LocalCluster

__all__ = ["dask_cluster"]


@contextmanager
def dask_cluster(workers: int = 2) -> Iterator[tuple[str, Client]]:
    """The scheduler's address and a client: ``workers`` processes of one thread each, as the fleet's
    ``dask worker --nthreads 1`` run; the scheduler's HTTP endpoint on a free port (not 8787: another
    test's cluster may run)."""
    with (
        LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"},
        ) as cluster,
        Client(cluster) as client,  # type: ignore[no-untyped-call]
    ):
        yield cluster.scheduler_address, client
