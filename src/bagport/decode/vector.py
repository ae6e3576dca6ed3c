"""Turn numeric ROS messages into 1-D feature vectors, selecting by name or path."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.contract.plan import SourceSpec
from bagport.decode.custom import resolve_decoder
from bagport.decode.defaults import DEFAULT_FIELDS
from bagport.errors import DecodeError
from bagport.msgtypes import RosType

__all__ = ["VectorExtractor", "make_extractor"]

_JOINT_FIELDS = ("position", "velocity", "effort")
_SCALAR_TYPES = frozenset({RosType.FLOAT32, RosType.FLOAT64, RosType.INT32, RosType.INT64, RosType.BOOL})
_ARRAY_TYPES = frozenset(
    {RosType.FLOAT32_MULTI_ARRAY, RosType.FLOAT64_MULTI_ARRAY, "std_msgs/msg/Int32MultiArray"}
)
_JOY = "sensor_msgs/msg/Joy"
_PATH_PART = re.compile(r"^([A-Za-z_]\w*)(?:\[(\d+)\])?$")

Vector = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class VectorExtractor:
    """Extracts one source's values; ``names`` label each dimension."""

    names: tuple[str, ...]
    extract: Callable[[Any], Vector]

    def __call__(self, msg: Any) -> Vector:
        return self.extract(msg)


def _joint_selector(name: str) -> tuple[str, str]:
    field, sep, joint = name.partition(".")
    if sep and field in _JOINT_FIELDS:
        return field, joint
    return "position", name


class _JointStateExtractor:
    """Selects by joint name; the order of names may differ between messages."""

    def __init__(self, src: SourceSpec, selectors: tuple[tuple[str, str], ...]) -> None:
        self._src = src
        self._selectors = selectors
        self._fields = tuple(dict.fromkeys(field for field, _ in selectors))
        self._cache_key: tuple[str, ...] | None = None
        self._index: dict[str, npt.NDArray[np.intp]] = {}

    def _build_index(self, names: tuple[str, ...]) -> None:
        lookup = {name: i for i, name in enumerate(names)}
        missing = [joint for _, joint in self._selectors if joint not in lookup]
        if missing:
            raise DecodeError(
                f"joint(s) {missing} not in this JointState message (it has {list(names)})",
                topic=self._src.topic,
                fix="fix selector.names in the contract to use joint names the robot publishes.",
            )
        self._index = {}
        for field in self._fields:
            positions = [i for i, (f, _) in enumerate(self._selectors) if f == field]
            self._index[field] = np.array([lookup[self._selectors[i][1]] for i in positions], dtype=np.intp)
        self._cache_key = names

    def __call__(self, msg: Any) -> Vector:
        names = tuple(msg.name)
        if names != self._cache_key:
            self._build_index(names)
        out = np.empty(len(self._selectors), dtype=np.float64)
        for field in self._fields:
            values = np.asarray(getattr(msg, field), dtype=np.float64)
            if len(values) != len(names):
                raise DecodeError(
                    f"JointState.{field} has {len(values)} values for {len(names)} joint names",
                    topic=self._src.topic,
                    fix=f"select only fields the robot fills (e.g. position.<joint>), not {field}.<joint>.",
                )
            slots = [i for i, (f, _) in enumerate(self._selectors) if f == field]
            out[slots] = values[self._index[field]]
        return out


def field_at(msg: Any, path: str, topic: str) -> Any:
    """The value at dot path ``path`` (``a.b[2].c``) of a deserialised message."""
    value = msg
    for part in path.split("."):
        match = _PATH_PART.match(part)
        if match is None:
            raise DecodeError(f"selector {path!r} is not a dot path like 'a.b[2].c'", topic=topic)
        attr, index = match.group(1), match.group(2)
        if not hasattr(value, attr):
            fields = [f for f in getattr(value, "__dataclass_fields__", {}) if not f.startswith("_")]
            raise DecodeError(
                f"selector {path!r}: {type(value).__name__} has no field {attr!r} (fields: {fields})",
                topic=topic,
                fix="fix the dot path in the contract.",
            )
        value = getattr(value, attr)
        if index is not None:
            try:
                value = value[int(index)]
            except (IndexError, TypeError) as err:
                raise DecodeError(f"selector {path!r}: index {index} out of range", topic=topic) from err
    return value


def _resolve_path(msg: Any, path: str, src: SourceSpec) -> float:
    value = field_at(msg, path, src.topic)
    try:
        return float(value)
    except (TypeError, ValueError) as err:
        raise DecodeError(
            f"selector {path!r} points at a {type(value).__name__}, not a number",
            topic=src.topic,
            fix="select a numeric leaf field.",
        ) from err


def _paths_extractor(src: SourceSpec, paths: tuple[str, ...]) -> VectorExtractor:
    def extract(msg: Any) -> Vector:
        return np.array([_resolve_path(msg, p, src) for p in paths], dtype=np.float64)

    return VectorExtractor(paths, extract)


def _arrays_extractor(src: SourceSpec, first_msg: Any, fields: tuple[str, ...]) -> VectorExtractor:
    """Whole array fields, their lengths fixed by the first message."""
    widths = {name: len(getattr(first_msg, name)) for name in fields}

    def extract(msg: Any) -> Vector:
        parts = []
        for name, width in widths.items():
            values = np.asarray(getattr(msg, name), dtype=np.float64)
            if values.shape != (width,):
                raise DecodeError(
                    f"{name} length changed from {width} to {values.shape[0]}",
                    topic=src.topic,
                    fix=f"select fixed elements with selector.names: ['{name}[0]', ...].",
                )
            parts.append(values)
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    names = tuple(f"{name}[{i}]" for name, width in widths.items() for i in range(width))
    return VectorExtractor(names, extract)


def make_extractor(src: SourceSpec, first_msg: Any) -> VectorExtractor:
    """Build the extractor for ``src``; the first message fixes unnamed dimensions."""
    if src.decoder is not None:
        decoder = resolve_decoder(src.decoder, where=f"contract ({src.key} on {src.topic})")
        width = len(np.atleast_1d(np.asarray(decoder(first_msg, src))))
        names = src.names if len(src.names) == width else tuple(f"{src.key}_{i}" for i in range(width))

        def extract_custom(msg: Any) -> Vector:
            return np.atleast_1d(np.asarray(decoder(msg, src), dtype=np.float64))

        return VectorExtractor(names, extract_custom)
    if src.msgtype == RosType.JOINT_STATE:
        if src.names:
            selectors = tuple(_joint_selector(n) for n in src.names)
            names = src.names
        else:
            joints = tuple(first_msg.name)
            selectors = tuple(("position", j) for j in joints)
            names = tuple(f"position.{j}" for j in joints)
        return VectorExtractor(names, _JointStateExtractor(src, selectors))
    if src.names:
        return _paths_extractor(src, src.names)
    if src.msgtype in _SCALAR_TYPES:
        return _paths_extractor(src, ("data",))
    if src.msgtype in DEFAULT_FIELDS:
        return _paths_extractor(src, DEFAULT_FIELDS[src.msgtype])
    if src.msgtype in _ARRAY_TYPES:
        return _arrays_extractor(src, first_msg, ("data",))
    if src.msgtype == _JOY:
        return _arrays_extractor(src, first_msg, ("axes", "buttons"))
    raise DecodeError(
        f"bagport does not know which fields of {src.msgtype} to use for {src.key!r}",
        topic=src.topic,
        fix="list the fields in selector.names (dot paths such as 'twist.linear.x'), or set 'decoder: module:function'.",
    )
