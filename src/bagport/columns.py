"""Arrow helpers shared by the converter, the writer and tests."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

__all__ = ["vector_column"]


def vector_column(table: pa.Table, name: str) -> npt.NDArray[np.float64]:
    """A fixed-size-list column as a (rows, dims) float64 array."""
    column = table.column(name)
    width = int(column.type.list_size)
    flat = pc.list_flatten(column).to_numpy()
    return np.asarray(flat, dtype=np.float64).reshape(-1, width)
