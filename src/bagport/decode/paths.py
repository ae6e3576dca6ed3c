"""Reading numbers out of messages by dot path (``pose.pose.position.x``, ``axes[1]``)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.errors import DecodeError

__all__ = ["Vector", "VectorExtractor", "field_at", "paths_extractor", "resolve_path"]

_PATH_PART = re.compile(r"^([A-Za-z_]\w*)(?:\[(-?\d+)\])?$")

Vector = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class VectorExtractor:
    """Extracts one source's values; ``names`` label each dimension."""

    names: tuple[str, ...]
    extract: Callable[[Any], Vector]

    def __call__(self, msg: Any) -> Vector:
        return self.extract(msg)


def field_at(msg: Any, path: str, topic: str) -> Any:
    """The value at dot path ``path`` (``a.b[2].c``) of a deserialised message; negative indices
    count from the end."""
    value = msg
    for part in path.split("."):
        match = _PATH_PART.match(part)
        if match is None:
            raise DecodeError(f"selector {path!r} is not a dot path like 'a.b[2].c'", topic=topic)
        attr, index = match.group(1), match.group(2)
        if not hasattr(value, attr):
            fields = [f for f in getattr(value, "__dataclass_fields__", {}) if not f.startswith("_")]
            name = getattr(value, "__msgtype__", type(value).__name__)  # the ROS name, not rosbags' class
            raise DecodeError(
                f"selector {path!r}: {name} has no field {attr!r} (fields: {fields})",
                topic=topic,
                fix="fix selector.names in the contract.",
            )
        value = getattr(value, attr)
        if index is not None:
            try:
                value = value[int(index)]
            except (IndexError, TypeError) as err:
                size = len(value) if hasattr(value, "__len__") else "no"
                raise DecodeError(
                    f"selector {path!r}: index {index} out of range ({attr} has {size} elements)",
                    topic=topic,
                    fix="fix the index in selector.names.",
                ) from err
    return value


def resolve_path(msg: Any, path: str, topic: str) -> float:
    """The number at ``path`` in ``msg``; negative indices count from the end."""
    value = field_at(msg, path, topic)
    try:
        return float(value)
    except (TypeError, ValueError) as err:
        raise DecodeError(
            f"selector {path!r} points at a {type(value).__name__}, not a number",
            topic=topic,
            fix="select a numeric leaf field.",
        ) from err


def paths_extractor(
    topic: str, paths: tuple[str, ...], names: tuple[str, ...] | None = None
) -> VectorExtractor:
    def extract(msg: Any) -> Vector:
        return np.array([resolve_path(msg, p, topic) for p in paths], dtype=np.float64)

    return VectorExtractor(names if names is not None else paths, extract)
