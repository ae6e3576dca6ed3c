"""The one validated configuration object a conversion run takes."""

from __future__ import annotations

import json
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt, model_validator

from bagport.video.settings import default_encoder

__all__ = ["ConvertConfig"]


class ConvertConfig(BaseModel):
    """Parameters of ``bagport convert`` / the Prefect ``convert`` flow."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    manifest: str | None = Field(default=None, description="Manifest YAML: local path or fsspec URI.")
    bags_glob: str | None = Field(
        default=None, description="Instead of a manifest: every bag matching this glob (local or fsspec URI)."
    )
    contract: str = Field(description="Contract YAML: local path or fsspec URI.")
    output: str = Field(description="Dataset root folder to create (LeRobot's `root`).")
    repo_id: str | None = Field(
        default=None, description="LeRobot repo id; default 'local/<output folder name>'."
    )
    staging: str | None = Field(
        default=None, description="Staging store URI; default '<output>.staging' beside it."
    )
    workers: PositiveInt | None = Field(
        default=None, description="Parallel episode workers; default: CPU count."
    )
    runner: Literal["process", "thread", "dask", "ray"] = Field(
        default="process", description="Task runner for the fan-out."
    )
    dask_address: str | None = Field(
        default=None,
        description="Existing Dask scheduler (tcp://host:port); default: a local cluster of processes.",
    )
    ray_address: str | None = Field(
        default=None,
        description="Existing Ray cluster (ray://head:10001, or 'auto' for the one this machine belongs to); "
        "default: a local Ray instance with `workers` CPUs, started for the run.",
    )
    encoder: dict[str, Any] = Field(
        default_factory=default_encoder,
        description="Video encoder settings (see configs/codecs); default: H.264 (bagport.video.DEFAULT_ENCODER).",
    )
    chunks_size: PositiveInt = 1000
    data_files_size_in_mb: PositiveFloat = 100
    video_files_size_in_mb: PositiveFloat = 200
    overwrite: bool = False
    keep_staging: bool = False
    append: bool = Field(
        default=False,
        description="Add new episodes to the dataset at output (created if missing); bags already in it are skipped.",
    )
    qa: str | None = Field(
        default=None, description="QA thresholds YAML (see configs/qa.yaml); default: built-in."
    )
    on_qa_fail: Literal["exclude", "keep", "fail_run"] | None = Field(
        default=None, description="Override the QA file's on_fail: exclude, keep (and flag) or fail_run."
    )
    keep_failed: bool = Field(
        default=False,
        description="Keep episodes labelled failed or discarded by episode events (default: leave them out).",
    )
    msg_path: str | None = Field(
        default=None,
        description="Folder of .msg files (<pkg>/msg/<Type>.msg) for types the bags do not embed; "
        "read once and sent to the workers with each episode.",
    )
    formats: tuple[Literal["lerobot", "hdf5", "robodm"], ...] = Field(
        default=("lerobot",),
        description="Outputs to write from the same staged episodes: lerobot (at output), hdf5 (ALOHA/ACT "
        "layout, one file per episode), robodm (one Robo-DM trajectory per episode); the first non-LeRobot "
        "one goes to output when lerobot is not asked for, the others to '<output>.<format>'.",
    )
    hdf5_jpeg_quality: int | None = Field(
        default=None,
        ge=1,
        le=100,
        description="HDF5 images as JPEG of this quality, like ALOHA's compressed episodes; default: raw uint8.",
    )
    fail_fast: bool = Field(
        default=False,
        description="Stop the run at the first bag that fails to convert (or fails QA under fail_run); "
        "default: the bag is reported and the other episodes continue.",
    )

    @model_validator(mode="after")
    def _one_bag_source(self) -> ConvertConfig:
        if (self.manifest is None) == (self.bags_glob is None):
            raise ValueError("give exactly one of manifest and bags_glob")
        return self

    @model_validator(mode="after")
    def _address_of_its_runner(self) -> ConvertConfig:
        for runner, address in (("dask", self.dask_address), ("ray", self.ray_address)):
            if address is not None and self.runner != runner:
                raise ValueError(
                    f"{runner}_address {address!r} is only used with runner {runner!r}, not {self.runner!r}: "
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
