"""Flows meant for deployments (see ``prefect.yaml``): scheduled fleet ingestion and reconversion.

``ingest`` converts the bags under a glob that the dataset does not hold yet and appends them
(safe to run again after a failure: finished episodes are kept in the staging store and reused,
bags already in the dataset are skipped). ``reconvert`` re-runs a manifest with a (new) contract
into a fresh dataset. Both run the episodes in a process pool, or on Dask with ``dask_address``.
"""

from __future__ import annotations

from typing import Any

from prefect import flow

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.video.settings import default_encoder
from flows.convert import run_config

__all__ = ["ingest", "reconvert"]


@flow(name="bagport-ingest", flow_run_name="ingest {bags_glob}")
def ingest(
    bags_glob: str,
    contract: str,
    output: str,
    staging: str | None = None,
    qa: str | None = None,
    encoder: dict[str, Any] | None = None,
    workers: int | None = None,
    dask_address: str | None = None,
) -> DatasetReport:
    """Append the bags matching ``bags_glob`` that are not in the dataset at ``output`` yet."""
    config = ConvertConfig(
        bags_glob=bags_glob,
        contract=contract,
        output=output,
        staging=staging,
        qa=qa,
        encoder=encoder or default_encoder(),
        workers=workers,
        runner="dask" if dask_address else "process",
        dask_address=dask_address,
        append=True,
    )
    return run_config(config)


@flow(name="bagport-reconvert", flow_run_name="reconvert {manifest} -> {output}")
def reconvert(
    manifest: str,
    contract: str,
    output: str,
    overwrite: bool = False,
    qa: str | None = None,
    encoder: dict[str, Any] | None = None,
    workers: int | None = None,
    dask_address: str | None = None,
) -> DatasetReport:
    """Convert a manifest with a (new) contract into ``output``."""
    config = ConvertConfig(
        manifest=manifest,
        contract=contract,
        output=output,
        overwrite=overwrite,
        qa=qa,
        encoder=encoder or default_encoder(),
        workers=workers,
        runner="dask" if dask_address else "process",
        dask_address=dask_address,
    )
    return run_config(config)
