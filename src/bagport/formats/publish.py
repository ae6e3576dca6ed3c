"""Publishing another format's output with the LeRobot writer's guarantees
(:mod:`bagport.dataset.replace`): what a crashed write left is undone first
(:func:`bagport.dataset.repair.repair_dataset`); every output has ``meta/info.json``, the file the local
recovery looks for in a complete previous version, and which the upload writes last.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from bagport.dataset.repair import repair_dataset
from bagport.dataset.replace import publish_built as publish_whole
from bagport.dataset.replace import refuse_existing

__all__ = ["check_output_free", "publish_built"]


def check_output_free(output: str, *, overwrite: bool) -> None:
    """Undo a crashed write into ``output``; refuse an existing output unless ``overwrite``."""
    repair_dataset(output)
    refuse_existing(output, overwrite=overwrite)


def publish_built[Report](output: str, *, overwrite: bool, build: Callable[[Path], Report]) -> Report:
    """``build(root)`` writes the output's files under a fresh local ``root``; they replace ``output``
    whole, or nothing changes there."""
    check_output_free(output, overwrite=overwrite)
    return publish_whole(output, build, overwrite=overwrite)
