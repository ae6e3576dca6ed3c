"""Outputs other than LeRobot, written from the same staged episodes (no second read of the bags).

``--format lerobot,hdf5,robodm``: the LeRobot dataset (or, without ``lerobot``, the first format
listed) goes to ``--output``, every other format to ``<output>.<format>`` (see
:meth:`bagport.config.ConvertConfig.format_outputs`). Each writer publishes as the LeRobot writer
does (:mod:`bagport.formats.publish`) and writes ``meta/info.json`` and ``meta/provenance/``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from typing import Any

from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.formats.publish import check_output_free
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

__all__ = ["check_format_outputs", "write_formats"]


def check_format_outputs(config: ConvertConfig) -> None:
    """Before any work: each format's package is installed, every output but the LeRobot one is free
    (or ``overwrite``), a crashed write into it undone."""
    for fmt in config.formats:
        if fmt == "hdf5" and importlib.util.find_spec("h5py") is None:
            from bagport.formats.hdf5 import Hdf5MissingError  # noqa: PLC0415

            raise Hdf5MissingError("no module named h5py")
        if fmt == "robodm" and importlib.util.find_spec("robodm") is None:
            from bagport.formats.robodm import RobodmMissingError  # noqa: PLC0415

            raise RobodmMissingError("no module named robodm")
    for name, output in config.format_outputs().items():
        if name != "lerobot" and output != config.output:
            check_output_free(output, overwrite=config.overwrite)


def write_formats(
    summaries: Sequence[EpisodeSummary],
    config: ConvertConfig,
    *,
    robot_type: str,
    run_record: dict[str, Any],
    qa: Sequence[QAEntry],
) -> dict[str, DatasetReport]:
    """Write every format but LeRobot that ``config`` asks for; their reports by format."""
    reports: dict[str, DatasetReport] = {}
    for fmt, output in config.format_outputs().items():
        if fmt == "hdf5":
            from bagport.formats.hdf5 import write_hdf5_dataset  # noqa: PLC0415 - needs the hdf5 extra

            reports[fmt] = write_hdf5_dataset(
                summaries,
                output,
                robot_type=robot_type,
                run_record=run_record,
                overwrite=config.overwrite,
                qa=qa,
                jpeg_quality=config.hdf5_jpeg_quality,
            )
        elif fmt == "robodm":
            from bagport.formats.robodm import write_robodm_dataset  # noqa: PLC0415 - needs the robodm extra

            reports[fmt] = write_robodm_dataset(
                summaries,
                output,
                robot_type=robot_type,
                run_record=run_record,
                overwrite=config.overwrite,
                qa=qa,
            )
    return reports
