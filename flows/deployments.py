"""Flows meant for deployments (see ``prefect.yaml``): scheduled fleet ingestion and reconversion.

``ingest`` converts the bags under a glob that the dataset does not hold yet and appends them
(safe to run again after a failure: finished episodes are kept in the staging store and reused,
bags already in the dataset are skipped). ``reconvert`` re-runs a manifest with a (new) contract
into a fresh dataset; with the staging store of an earlier run (``keep_staging``) it reuses the camera
clips the contract change does not touch. Both run the episodes in a process pool, or on Dask with
``dask_address``.

``prefect.yaml`` fills the parameters from environment variables when ``prefect deploy`` runs
(``{{ $BAGPORT_OUTPUT }}``...). A parameter still holding such a placeholder was not set: a required
one stops the run with one paragraph naming the variable, an optional one counts as unset.
"""

from __future__ import annotations

import re
from typing import Any
from uuid import UUID

from prefect import flow
from prefect.client.orchestration import get_client
from prefect.client.schemas.objects import State
from prefect.runtime import flow_run

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.errors import BagportError
from bagport.video.settings import default_encoder
from flows.artifacts import publish_run_artifacts
from flows.convert import run_config
from flows.run_story import RunCounts, completed_state, started_name

__all__ = ["ParameterNotSetError", "ingest", "reconvert"]

_PLACEHOLDER = re.compile(r"^\{\{\s*\$(\w+)\s*\}\}$")


class ParameterNotSetError(BagportError):
    """A deployment parameter still holds the ``{{ $VAR }}`` placeholder of prefect.yaml."""


def _required(name: str, value: str) -> str:
    found = _PLACEHOLDER.match(value.strip())
    if found:
        raise ParameterNotSetError(
            f"deployment parameter {name!r} is not set: it still holds prefect.yaml's placeholder {value!r}, "
            f"because ${found.group(1)} was not set when `prefect deploy` ran. Fix: export {found.group(1)}=... "
            f"and run `prefect deploy --all` again, or start the run with `--param {name}=...` "
            "(or set it in the UI: deployment, Edit, Parameters)."
        )
    return value


def _optional(value: str | None) -> str | None:
    return None if value is None or not value.strip() or _PLACEHOLDER.match(value.strip()) else value


def _finish(kind: str, report: DatasetReport) -> DatasetReport | State[Any]:
    """Name the run after what it added, put the run's artifacts on it, and its state."""
    counts = RunCounts.of(report)
    run_id = flow_run.get_id()
    if run_id is not None:
        name = f"{flow_run.get_name() or kind}: +{counts.converted} episode(s)"
        if counts.excluded:
            name += f", {counts.excluded} excluded"
        with get_client(sync_client=True) as client:
            client.update_flow_run(UUID(run_id), name=name)
    publish_run_artifacts(report)
    return completed_state(report)


@flow(name="bagport-ingest", flow_run_name=lambda: started_name("ingest"))
def ingest(
    bags_glob: str,
    contract: str,
    output: str,
    staging: str | None = None,
    keep_staging: bool = False,
    qa: str | None = None,
    encoder: dict[str, Any] | None = None,
    workers: int | None = None,
    dask_address: str | None = None,
) -> DatasetReport | State[Any]:
    """Append the bags matching ``bags_glob`` that are not in the dataset at ``output`` yet."""
    dask = _optional(dask_address)
    config = ConvertConfig(
        bags_glob=_required("bags_glob", bags_glob),
        contract=_required("contract", contract),
        output=_required("output", output),
        staging=_optional(staging),
        keep_staging=keep_staging,
        qa=_optional(qa),
        encoder=encoder or default_encoder(),
        workers=workers,
        runner="dask" if dask else "process",
        dask_address=dask,
        append=True,
    )
    return _finish("ingest", run_config(config))


@flow(name="bagport-reconvert", flow_run_name=lambda: started_name("reconvert"))
def reconvert(
    manifest: str,
    contract: str,
    output: str,
    overwrite: bool = False,
    staging: str | None = None,
    keep_staging: bool = False,
    qa: str | None = None,
    encoder: dict[str, Any] | None = None,
    workers: int | None = None,
    dask_address: str | None = None,
) -> DatasetReport | State[Any]:
    """Convert a manifest with a (new) contract into ``output``; camera clips staged by an earlier run
    in ``staging`` (kept with ``keep_staging``) that the new contract does not change are reused."""
    dask = _optional(dask_address)
    config = ConvertConfig(
        manifest=_required("manifest", manifest),
        contract=_required("contract", contract),
        output=_required("output", output),
        overwrite=overwrite,
        staging=_optional(staging),
        keep_staging=keep_staging,
        qa=_optional(qa),
        encoder=encoder or default_encoder(),
        workers=workers,
        runner="dask" if dask else "process",
        dask_address=dask,
    )
    return _finish("reconvert", run_config(config))
