"""Writing and validating LeRobot v3.0 datasets."""

from __future__ import annotations

from bagport.dataset.meta import DatasetLimits
from bagport.dataset.write import DatasetReport, write_dataset

__all__ = ["DatasetLimits", "DatasetReport", "write_dataset"]
