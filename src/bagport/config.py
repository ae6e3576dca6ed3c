"""The one validated configuration object a conversion run takes, and how each of its fields is written on
the command line (:class:`CliOption`): ``bagport convert``'s options, ``--config run.yaml`` and the Prefect
deployments' ``config`` parameter all come from the fields below."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt, model_validator
from pydantic.fields import FieldInfo

from bagport.yamlsource import YamlJson

__all__ = ["RUNNER_ADDRESSES", "CliOption", "ConvertConfig", "cli_option"]


@dataclass(frozen=True)
class CliOption:
    """How a :class:`ConvertConfig` field is written on ``bagport convert``'s command line, where it differs
    from the defaults: ``--<field-name>``, its metavar the flag's name in capitals, its value's type, choices
    and default read from the field, its help text the field's description.

    ``named``: the option (and the run.yaml key) names a preset the application loads into the field (the
    encoder settings: ``codec``). ``group``: the fields of one group are mutually exclusive on the command
    line (and a group member given there replaces the others' values from ``--config``).
    """

    flag: str | None = None
    metavar: str | None = None
    named: str | None = None
    group: str | None = None


def cli_option(name: str, field: FieldInfo) -> CliOption:
    """The field's :class:`CliOption`, its defaults filled in (flag, metavar)."""
    given = next((m for m in field.metadata if isinstance(m, CliOption)), CliOption())
    flag = given.flag or "--" + (given.named or name).replace("_", "-")
    metavar = given.metavar or flag.lstrip("-").replace("-", "_").upper()
    return CliOption(flag=flag, metavar=metavar, named=given.named, group=given.group)


def _default_encoder() -> dict[str, YamlJson]:
    from bagport.video.settings import default_encoder  # noqa: PLC0415 - no numpy/av for `bagport --help`

    return default_encoder()


_BAGS = CliOption(group="bags")
RUNNER_ADDRESSES = {"dask": "dask_address", "ray": "ray_address"}
"""The runners that can use an existing cluster, and the :class:`ConvertConfig` field of its address."""


class ConvertConfig(BaseModel):
    """Parameters of ``bagport convert`` / the Prefect ``convert`` flow and the deployments. Each field's
    description is its help text on the command line (the docs' CLI reference shows it)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    manifest: Annotated[str | None, _BAGS] = Field(
        default=None,
        description="manifest YAML (bags: [{uri, task, metadata, start_s/end_s or start_ns/end_ns}]); see the "
        "getting-started page",
    )
    bags_glob: Annotated[str | None, CliOption(flag="--glob", group="bags")] = Field(
        default=None,
        description="every bag matching this glob instead of a manifest, e.g. 's3://fleet/2026-*/*.mcap'",
    )
    contract: str = Field(description="contract YAML (Rosetta-compatible); required (here or in --config)")
    output: str = Field(
        description="the dataset folder itself (LeRobot's root), local or any fsspec URI (s3://...); it must "
        "not exist unless --overwrite or --append; required (here or in --config)"
    )
    repo_id: str | None = Field(
        default=None, description="LeRobot repo id recorded for the dataset (default: local/<name of OUT>)"
    )
    staging: str | None = Field(
        default=None,
        description="staging store URI (default: <output>.staging beside it), removed after success unless "
        "--keep-staging; after a failure it keeps every finished episode (and each bag's split into episodes) "
        "and a re-run skips them (same bag files, contract, codec, QA settings, task, --msg-path definitions "
        "and bagport version)",
    )
    workers: PositiveInt | None = Field(default=None, description="parallel episodes (default: CPU count)")
    runner: Literal["process", "thread", "dask", "ray"] = Field(
        default="process",
        description="process pool (default), threads, Dask (a local cluster of worker processes, or "
        "--dask-address) or Ray (a local instance of --workers CPUs started for the run, or --ray-address; "
        "needs the extra: pip install 'bagport[ray]'); an address without its runner is an error (exit code 2)",
    )
    dask_address: str | None = Field(
        default=None, description="existing Dask scheduler, e.g. tcp://10.0.0.5:8786"
    )
    ray_address: str | None = Field(
        default=None,
        description="existing Ray cluster, e.g. ray://10.0.0.5:10001, or 'auto' (the cluster this machine "
        "belongs to)",
    )
    encoder: Annotated[dict[str, YamlJson], CliOption(named="codec")] = Field(
        default_factory=_default_encoder,
        description="encoder preset name in configs/codecs or a YAML file (default: h264-fast; LeRobot's: "
        "lerobot-default)",
    )
    overwrite: bool = Field(
        default=False,
        description="replace an existing dataset at --output (the old dataset stays in place until the new "
        "one is complete); a folder that is not a dataset (no meta/info.json) and is not empty, or one that "
        "holds a bag of the manifest, is refused",
    )
    append: bool = Field(
        default=False,
        description="add the bags not yet in the dataset at --output as new episodes (created if missing); see "
        "the fleet page",
    )
    keep_staging: bool = Field(default=False, description="keep staged episodes after success")
    chunks_size: PositiveInt = Field(default=1000, description="files per chunk-NNN folder (default: 1000)")
    data_files_size_in_mb: PositiveFloat = Field(
        default=100, description="data file rotation size (default: 100)"
    )
    video_files_size_in_mb: PositiveFloat = Field(
        default=200, description="video file rotation size (default: 200)"
    )
    qa: str | None = Field(
        default=None, description="QA thresholds YAML (default: built-in, see configs/qa.yaml)"
    )
    on_qa_fail: Literal["exclude", "keep", "fail_run"] | None = Field(
        default=None,
        description="episodes failing QA or conversion: leave out and list (exclude), keep and flag (keep), or "
        "fail the run with nothing written (fail_run) (default: the QA file's on_fail, built-in exclude)",
    )
    keep_failed: bool = Field(
        default=False,
        description="keep episodes labelled failed or discarded by episode events (default: leave them out, "
        "listed)",
    )
    fail_fast: bool = Field(
        default=False,
        description="stop at the first bag that fails to convert, writing nothing (default: report it, convert "
        "the others)",
    )
    formats: Annotated[tuple[Literal["lerobot", "hdf5", "robodm"], ...], CliOption(flag="--format")] = Field(
        default=("lerobot",),
        description="outputs, comma-separated: lerobot (default), hdf5 (ALOHA/ACT layout; extra bagport[hdf5]), "
        "robodm (Robo-DM trajectories; extra bagport[robodm]); LeRobot's goes to --output, each other one to "
        "<output>.<format>",
    )
    hdf5_jpeg_quality: Annotated[int | None, CliOption(flag="--hdf5-jpeg", metavar="QUALITY")] = Field(
        default=None,
        ge=1,
        le=100,
        description="HDF5 images as JPEG of this quality (1-100), like ALOHA's compressed episodes (default: "
        "raw uint8)",
    )
    msg_path: str | None = Field(
        default=None,
        description="folder of .msg files (<pkg>/msg/<Type>.msg) for message types the bags do not embed",
    )

    @model_validator(mode="after")
    def _one_bag_source(self) -> ConvertConfig:
        if (self.manifest is None) == (self.bags_glob is None):
            raise ValueError(
                "give exactly one of --manifest and --glob (manifest or bags_glob in a --config file)"
            )
        return self

    @model_validator(mode="after")
    def _replace_or_add(self) -> ConvertConfig:
        if self.overwrite and self.append:
            raise ValueError(
                "overwrite and append both given: --overwrite replaces the dataset, --append adds to it; "
                "give one (to append with a --config file that sets overwrite: true, take that line out)"
            )
        return self

    @model_validator(mode="after")
    def _address_of_its_runner(self) -> ConvertConfig:
        for runner, name in RUNNER_ADDRESSES.items():
            address = getattr(self, name)
            if address is not None and self.runner != runner:
                raise ValueError(
                    f"{name} {address!r} is only used with runner {runner!r}, not {self.runner!r}: "
                    f"add --runner {runner} (runner: {runner}), or leave the address out"
                )
        return self

    @model_validator(mode="after")
    def _formats_usable(self) -> ConvertConfig:
        if not self.formats or len(set(self.formats)) != len(self.formats):
            raise ValueError(f"formats {list(self.formats)}: give each of lerobot, hdf5, robodm at most once")
        if self.append and self.formats != ("lerobot",):
            raise ValueError(
                "append adds to a LeRobot dataset only: leave --format out, or convert into a new --output"
            )
        if self.hdf5_jpeg_quality is not None and "hdf5" not in self.formats:
            raise ValueError(
                "hdf5_jpeg_quality (--hdf5-jpeg) applies to --format hdf5 only: add hdf5, or leave it out"
            )
        return self

    def format_outputs(self) -> dict[str, str]:
        """Each format's output: LeRobot's (else the first format's) at ``output``, the others beside it."""
        primary = "lerobot" if "lerobot" in self.formats else self.formats[0]
        base = self.output.rstrip("/")
        return {fmt: self.output if fmt == primary else f"{base}.{fmt}" for fmt in self.formats}

    def manifest_text(self) -> tuple[str, str] | None:
        """``(yaml, source name)`` of the one-entry manifest a ``bags_glob`` stands for."""
        if self.bags_glob is None:
            return None
        return f"bags:\n  - uri: {json.dumps(self.bags_glob)}\n", f"--glob {self.bags_glob}"

    def resolved_repo_id(self) -> str:
        name = self.output.rstrip("/").rsplit("/", 1)[-1] or "dataset"
        return self.repo_id or f"local/{name}"

    def resolved_staging(self) -> str:
        return self.staging or f"{self.output.rstrip('/')}.staging"

    def resolved_workers(self) -> int:
        """Parallel episodes: ``workers``, else this machine's CPU count."""
        return self.workers or os.cpu_count() or 1

    def on_local_pool(self) -> bool:
        """Whether the episodes run on the local process pool (``runner: process``, more than one worker;
        a single worker runs on a thread)."""
        return self.runner == "process" and self.resolved_workers() > 1
