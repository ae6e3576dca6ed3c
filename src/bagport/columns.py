"""Arrow helpers shared by the converter, the writer and tests."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

__all__ = ["column_matrix", "vector_column"]


def vector_column(table: pa.Table, name: str) -> npt.NDArray[np.float64]:
    """A fixed-size-list column as a (rows, dims) float64 array."""
    return column_matrix(table.column(name))


def column_matrix(column: pa.Array[Any] | pa.ChunkedArray[Any]) -> npt.NDArray[np.float64]:
    """A list column as a (rows, dims) float64 array, a scalar column as (rows, 1).

    Copies where Arrow cannot hand out a view (bool columns are bit-packed).
    """
    rows = len(column)
    if pa.types.is_fixed_size_list(column.type) or pa.types.is_list(column.type):
        flat = np.asarray(pc.list_flatten(column).to_numpy(zero_copy_only=False), dtype=np.float64)
        width = (
            column.type.list_size if pa.types.is_fixed_size_list(column.type) else flat.size // max(rows, 1)
        )
        return flat.reshape(rows, width)
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(rows, 1)
