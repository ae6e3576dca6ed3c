"""``bagport convert``'s run options as one :class:`~bagport.config.ConvertConfig`: from ``--config``, the
command line and the codec presets."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from bagport.errors import BagportError

if TYPE_CHECKING:
    from bagport.config import ConvertConfig

__all__ = ["CONFIG_FIELDS", "convert_config", "load_encoder"]


def load_encoder(value: str | None) -> dict[str, Any]:
    if not value:
        from bagport.video.settings import default_encoder  # noqa: PLC0415 - keep `--help` fast

        return default_encoder()
    path = Path(value)
    if not path.is_file():
        preset = Path(__file__).resolve().parent.parent / "configs" / "codecs" / f"{value}.yaml"
        if not preset.is_file():
            raise BagportError(f"--codec {value!r}: no such file and no preset configs/codecs/{value}.yaml")
        path = preset
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict):
        raise BagportError(f"--codec {value}: must be a YAML mapping of encoder settings")
    return data


CONFIG_FIELDS = {
    "manifest": "manifest", "glob": "bags_glob", "contract": "contract", "output": "output",
    "repo_id": "repo_id", "staging": "staging", "workers": "workers", "runner": "runner",
    "dask_address": "dask_address", "ray_address": "ray_address", "codec": "codec",
    "overwrite": "overwrite", "append": "append", "keep_staging": "keep_staging",
    "chunks_size": "chunks_size", "data_files_size_in_mb": "data_files_size_in_mb",
    "video_files_size_in_mb": "video_files_size_in_mb", "qa": "qa", "on_qa_fail": "on_qa_fail",
    "keep_failed": "keep_failed", "msg_path": "msg_path", "fail_fast": "fail_fast", "format": "formats",
    "hdf5_jpeg": "hdf5_jpeg_quality",
}  # fmt: skip
"""``convert``'s options (argparse dest) -> the :class:`ConvertConfig` field each sets (``codec``: a preset
or file, loaded into ``encoder``); a test checks every field is reachable."""


def _config_file(path: str) -> dict[str, Any]:
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) if Path(path).is_file() else None
    if not isinstance(data, dict):
        raise BagportError(
            f"--config {path}: not a YAML mapping of run options (or no such file). Fix: give a file such as "
            "'manifest: fleet.yaml\ncontract: robot.yaml\noutput: datasets/robot\nrunner: dask'."
        )
    return dict(data)


def convert_config(args: argparse.Namespace, defaults: dict[str, Any]) -> ConvertConfig:
    """The run's :class:`ConvertConfig`: the ``--config`` file's options, overridden by those given on the
    command line (an option left at its parser default, ``defaults``, does not override the file)."""
    from bagport.config import ConvertConfig  # noqa: PLC0415 - keep `--help` fast

    given = {
        field: getattr(args, dest)
        for dest, field in CONFIG_FIELDS.items()
        if getattr(args, dest) != defaults[dest]
    }
    options = _config_file(args.config) if args.config else {}
    for one, other in (("manifest", "bags_glob"), ("bags_glob", "manifest")):
        if one in given:
            options.pop(other, None)  # the command line's bag source replaces the file's
    options.update(given)
    if isinstance(options.get("formats"), str):
        options["formats"] = tuple(f.strip() for f in options["formats"].split(",") if f.strip())
    if "codec" in options or "encoder" not in options:
        options["encoder"] = load_encoder(options.pop("codec", None))
    return ConvertConfig(**options)
