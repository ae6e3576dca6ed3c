"""Flows meant for deployments (see ``prefect.yaml``): scheduled fleet ingestion and reconversion.

Both take one parameter, ``config``: a :class:`~bagport.config.ConvertConfig`, keyed as ``bagport convert
--config run.yaml`` is (every field, and ``codec`` for a preset), so a deployment has every option of the
command line, every runner included (``runner: ray`` with ``ray_address``, or ``dask`` with
``dask_address``). ``ingest`` converts the bags that the dataset does not hold yet and appends them
(``append`` is always on; safe to run again after a failure: finished episodes are kept in the staging store
and reused, bags already in the dataset are skipped). ``reconvert`` runs its config as given, e.g. a
manifest with a (new) contract into a fresh dataset; with the staging store of an earlier run
(``keep_staging``) it reuses the camera clips the contract change does not touch.

``prefect.yaml`` fills the config from environment variables when ``prefect deploy`` runs
(``{{ $BAGPORT_OUTPUT }}``...); a variable that was not set leaves its value empty (or, in a deployment
made without templating, the placeholder itself). Such a value was not set: a required one (the contract,
the output, the bag source) stops the run with one paragraph saying so, an optional one counts as unset. A
config naming an address but no runner runs on that address's runner.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any
from uuid import UUID

from prefect import flow
from prefect.client.orchestration import get_client
from prefect.client.schemas.objects import State
from prefect.runtime import flow_run
from pydantic import Field, model_validator

from bagport.config import RUNNER_ADDRESSES, ConvertConfig, cli_option
from bagport.dataset import DatasetReport
from bagport.errors import BagportError
from flows.artifacts import publish_run_artifacts
from flows.cli_config import COMMAND_LINE_ONLY, resolve_options
from flows.convert import run_config
from flows.run_story import RunCounts, completed_state, started_name

__all__ = ["DeploymentConfig", "ParameterNotSetError", "ingest", "reconvert"]

_PLACEHOLDER = re.compile(r"^\{\{\s*\$(\w+)\s*\}\}$")
_BAG_SOURCE = tuple(
    name for name, f in ConvertConfig.model_fields.items() if cli_option(name, f).group == "bags"
)


class ParameterNotSetError(BagportError):
    """A deployment's config value was left unset: prefect.yaml's ``{{ $VAR }}`` placeholder, or the empty
    string ``prefect deploy`` puts in its place when the variable is not set."""


def _not_set(name: str, value: str) -> ParameterNotSetError:
    found = _PLACEHOLDER.match(value.strip())
    if found:
        why = f"it still holds prefect.yaml's placeholder {value!r}: ${found.group(1)} was not set"
        export = f"export {found.group(1)}=..."
    else:
        why = "it is empty: `prefect deploy` empties a placeholder whose environment variable is not set"
        export = f"export the variable prefect.yaml names for {name}"
    return ParameterNotSetError(
        f"deployment parameter 'config.{name}' is not set: {why}. Fix: {export} and run `prefect deploy --all` "
        f'again, or start the run with a whole config (`prefect deployment run NAME --param config=\'{{"{name}": '
        "..., ...}'`: a run's config replaces the deployment's), or set it in the UI (deployment, Edit, "
        "Parameters)."
    )


def _unfilled(value: Any) -> bool:
    """A placeholder nobody filled: still ``{{ $VAR }}``, or the empty string ``prefect deploy`` left."""
    return isinstance(value, str) and (not value.strip() or _PLACEHOLDER.match(value.strip()) is not None)


def _without_placeholders(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` without the placeholders nobody filled: a required value's stops the run
    (:class:`ParameterNotSetError`), an optional one's counts as unset."""
    kept = {name: value for name, value in values.items() if not _unfilled(value)}
    fields = ConvertConfig.model_fields
    for name, value in values.items():
        if name not in kept and name in fields and fields[name].is_required():
            raise _not_set(name, value)
    if not any(name in kept for name in _BAG_SOURCE):  # the bag source is required too
        for name in _BAG_SOURCE:
            if name in values:
                raise _not_set(name, values[name])
    return kept


class DeploymentConfig(ConvertConfig):
    """A deployment's ``config``: :class:`ConvertConfig`'s fields plus the presets a run.yaml may name
    (``codec``), with prefect.yaml's unfilled placeholders handled (see the module)."""

    codec: str | None = Field(default=None, description=ConvertConfig.model_fields["encoder"].description)

    @model_validator(mode="before")
    @classmethod
    def _as_a_run_yaml(cls, data: Any) -> Any:
        if isinstance(data, ConvertConfig) and not isinstance(data, DeploymentConfig):
            return data.model_dump()
        if not isinstance(data, Mapping):
            return data
        if flags := [name for name in data if name in COMMAND_LINE_ONLY]:
            what = f"{flags[0]} is an option" if len(flags) == 1 else f"{' and '.join(flags)} are options"
            raise ValueError(
                f"{what} of the `bagport convert` command, not of a run: a deployment's config has no such key. "
                "Fix: remove it from the config; push a dataset a deployment wrote with "
                "`bagport push OUT --repo-id ORG/NAME`."
            )
        values = _without_placeholders(data)
        addresses = [runner for runner, name in RUNNER_ADDRESSES.items() if values.get(name)]
        if "runner" not in values and len(addresses) == 1:
            values["runner"] = addresses[0]  # the address says which runner
        return resolve_options(values)

    def convert_config(self, **changes: Any) -> ConvertConfig:
        """The run's :class:`ConvertConfig` (the preset already loaded), with ``changes``."""
        return ConvertConfig(**self.model_dump(exclude={"codec"}) | changes)


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
def ingest(config: DeploymentConfig) -> DatasetReport | State[Any]:
    """Append the bags of ``config`` (its ``bags_glob`` or manifest) that the dataset at its ``output`` does
    not hold yet."""
    # an ingestion appends: a config written for --overwrite runs (overwrite: true) still ingests
    return _finish("ingest", run_config(config.convert_config(append=True, overwrite=False)))


@flow(name="bagport-reconvert", flow_run_name=lambda: started_name("reconvert"))
def reconvert(config: DeploymentConfig) -> DatasetReport | State[Any]:
    """Convert as ``config`` says, e.g. a manifest with a (new) contract into ``output``; camera clips staged
    by an earlier run in ``staging`` (kept with ``keep_staging``) that the new contract does not change are
    reused."""
    return _finish("reconvert", run_config(config.convert_config()))
