"""Selecting joints by name: sensor_msgs/JointState, trajectory_msgs/JointTrajectory and
control_msgs/MultiDOFCommand.

Selector grammar (Rosetta's, extended to trajectories):

- ``position.<joint>``, ``velocity.<joint>``, ``effort.<joint>`` (and ``acceleration.<joint>`` for
  trajectories); a bare ``<joint>`` means its position.
- JointTrajectory reads its first point unless the name starts with ``points[N].``
  (``points[-1].position.wrist`` is the last point).
- MultiDOFCommand (``dof_names``, ``values``, ``values_dot``): ``<dof>`` or ``value.<dof>`` is its value,
  ``value_dot.<dof>`` its rate; without a selector, every value.
- JointTrajectory names with an index (``points[0].positions[2]``, ``positions[2]`` = first point)
  or starting with ``time_from_start`` / ``header`` are dot paths into the message.
- JointState by position in the arrays, for drivers that publish ``name: []``: ``position[0]``,
  ``velocity[2]``, ``effort[-1]`` (dot-path indexing, as for any array); without a selector, such a
  message gives every position as ``position[0]``, ``position[1]``...
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from bagport.decode.paths import Vector, VectorExtractor, paths_extractor, resolve_path
from bagport.errors import DecodeError

__all__ = ["joint_state_extractor", "joint_trajectory_extractor", "multi_dof_extractor", "selected_joints"]

_STATE_FIELDS = {"position": "position", "velocity": "velocity", "effort": "effort"}
_POINT_FIELDS = {
    "position": "positions",
    "velocity": "velocities",
    "acceleration": "accelerations",
    "effort": "effort",
}
_DOF_FIELDS = {"position": "values", "value": "values", "value_dot": "values_dot"}
_POINT_PREFIX = re.compile(r"^points\[(-?\d+)\]\.")
_POINT_PATH = re.compile(r"^(?:(?:positions|velocities|accelerations|effort)\[-?\d+\]|time_from_start\.\w+)$")
_STATE_INDEX = re.compile(r"^(?:position|velocity|effort)\[-?\d+\]$")
_NAME_ORDERS = 16
"""Name orders whose joint positions :class:`_ByName` keeps (beyond, it starts over)."""


class _JointSelector(NamedTuple):
    point: int
    field: str
    """The message's array field (``position`` for JointState, ``positions`` for a trajectory point)."""
    joint: str


def _parse(name: str, fields: dict[str, str], point: int = 0) -> _JointSelector:
    field, sep, joint = name.partition(".")
    if sep and field in fields:
        return _JointSelector(point, fields[field], joint)
    return _JointSelector(point, fields["position"], name)


_SHARED_TOPIC_FIX = (
    "bagport reads one set of joints per topic: record the merged joint states on one topic "
    "(joint_state_publisher's source_list), or remap each publisher to a topic of its own and map each in its own "
    "contract entry."
)
_SHARED_JOINT_STATE_FIX = (
    "list the joints in selector.names: an entry then reads only the messages naming all its joints. Give each "
    "publisher's joints an entry of their own with the same key (their values are concatenated in declaration "
    "order)."
)


class _ByName:
    """Values by joint name; the order of names may change between messages (cached per order)."""

    def __init__(
        self,
        topic: str,
        what: str,
        selectors: tuple[_JointSelector, ...],
        names_of: Callable[[Any], tuple[str, ...]],
        values_of: Callable[[Any, int, str], Any],
    ) -> None:
        self._topic = topic
        self._what = what
        self._selectors = selectors
        self._names_of = names_of
        self._values_of = values_of
        self._groups = tuple(dict.fromkeys((s.point, s.field) for s in selectors))
        self._slots = {
            group: [i for i, s in enumerate(selectors) if (s.point, s.field) == group]
            for group in self._groups
        }
        self._indices: dict[tuple[str, ...], dict[tuple[int, str], npt.NDArray[np.intp]]] = {}
        """Where each selected joint is, per name order seen (two publishers on one topic alternate)."""

    def _index_of(self, names: tuple[str, ...]) -> dict[tuple[int, str], npt.NDArray[np.intp]]:
        index = self._indices.get(names)
        if index is None:
            if len(self._indices) >= _NAME_ORDERS:
                self._indices.clear()
            index = self._indices[names] = self._build_index(names)
        return index

    def _build_index(self, names: tuple[str, ...]) -> dict[tuple[int, str], npt.NDArray[np.intp]]:
        lookup = {name: i for i, name in enumerate(names)}
        missing = list(dict.fromkeys(s.joint for s in self._selectors if s.joint not in lookup))
        if missing:  # earlier messages on the topic had every selected joint: another publisher's
            raise self._missing(missing, names, shared=bool(self._indices))
        return {
            group: np.array([lookup[self._selectors[i].joint] for i in slots], dtype=np.intp)
            for group, slots in self._slots.items()
        }

    def _missing(self, missing: list[str], names: tuple[str, ...], *, shared: bool) -> DecodeError:
        said = f"joint(s) {missing} not in this {self._what} message (it has {list(names)})"
        if shared:
            said += (
                ", though earlier messages on the topic had them: publishers with different joints share the "
                "topic (an arm's and a gripper's driver, say)"
            )
            return DecodeError(said, topic=self._topic, fix=self._shared_fix)
        if not names:
            fix = (
                "fix selector.names in the contract to use joint names the robot publishes; it publishes none: "
                "select by index, e.g. 'position[0]'."
            )
        else:
            fix = (
                "fix selector.names in the contract to use joint names the robot publishes; if other messages on "
                f"this topic carry them, {self._shared_fix}"
            )
        return DecodeError(said, topic=self._topic, fix=fix)

    @property
    def _shared_fix(self) -> str:
        return _SHARED_JOINT_STATE_FIX if self._what == "JointState" else _SHARED_TOPIC_FIX

    def __call__(self, msg: Any) -> Vector:
        names = self._names_of(msg)
        index = self._index_of(names)
        out = np.empty(len(self._selectors), dtype=np.float64)
        for group in self._groups:
            point, field = group
            values = np.asarray(self._values_of(msg, point, field), dtype=np.float64)
            if len(values) != len(names):
                raise DecodeError(
                    f"{self._what}.{field} has {len(values)} values for {len(names)} joint names",
                    topic=self._topic,
                    fix=f"select only fields the robot fills (e.g. position.<joint>), not the {field}.",
                )
            out[self._slots[group]] = values[index[group]]
        return out


def selected_joints(names: tuple[str, ...]) -> tuple[str, ...]:
    """The joints a JointState selector list names (``position.j1`` and ``j1`` name ``j1``; an index such
    as ``position[0]`` names none), each once, in order."""
    return tuple(dict.fromkeys(_parse(n, _STATE_FIELDS).joint for n in names if not _STATE_INDEX.match(n)))


def joint_state_extractor(topic: str, names: tuple[str, ...], first_msg: Any) -> VectorExtractor:
    """By joint name or by index (``position[2]``); without names, every position in the first message's
    order (by index when it names no joints)."""
    if not names and len(first_msg.name):
        names = tuple(f"position.{j}" for j in first_msg.name)
    elif not names:
        names = tuple(f"position[{i}]" for i in range(len(first_msg.position)))
    indexed = [(i, n) for i, n in enumerate(names) if _STATE_INDEX.match(n)]
    joints = [(i, _parse(n, _STATE_FIELDS)) for i, n in enumerate(names) if not _STATE_INDEX.match(n)]
    if not joints:
        return paths_extractor(topic, names)

    def values_of(msg: Any, _point: int, field: str) -> Any:
        return getattr(msg, field)

    by_name = _ByName(topic, "JointState", tuple(s for _, s in joints), lambda m: tuple(m.name), values_of)
    if not indexed:
        return VectorExtractor(names, by_name)
    joint_slots = [i for i, _ in joints]

    def extract(msg: Any) -> Vector:
        out = np.empty(len(names), dtype=np.float64)
        out[joint_slots] = by_name(msg)
        for i, path in indexed:
            out[i] = resolve_path(msg, path, topic)
        return out

    return VectorExtractor(names, extract)


def _point(msg: Any, index: int, topic: str) -> Any:
    points = msg.points
    if not -len(points) <= index < len(points):
        raise DecodeError(
            f"JointTrajectory has {len(points)} point(s), the selector reads point {index}",
            topic=topic,
            fix="select an existing point (points[0] is the first, points[-1] the last).",
        )
    return points[index]


def joint_trajectory_extractor(topic: str, names: tuple[str, ...], first_msg: Any) -> VectorExtractor:
    """First point by default; joint selectors and dot paths may be mixed."""
    if not names:
        names = tuple(f"position.{j}" for j in first_msg.joint_names)
    joints: list[tuple[int, _JointSelector]] = []
    paths: list[tuple[int, str]] = []
    for i, name in enumerate(names):
        match = _POINT_PREFIX.match(name)
        point, rest = (int(match.group(1)), name[match.end() :]) if match else (0, name)
        if _POINT_PATH.match(rest):
            paths.append((i, f"points[{point}].{rest}"))
        elif name.startswith("header."):
            paths.append((i, name))
        else:
            joints.append((i, _parse(rest, _POINT_FIELDS, point)))

    def values_of(msg: Any, point: int, field: str) -> Any:
        return getattr(_point(msg, point, topic), field)

    by_name = _ByName(
        topic, "JointTrajectory", tuple(s for _, s in joints), lambda m: tuple(m.joint_names), values_of
    )
    joint_slots = [i for i, _ in joints]

    def extract(msg: Any) -> Vector:
        out = np.empty(len(names), dtype=np.float64)
        if joints:
            out[joint_slots] = by_name(msg)
        for i, path in paths:
            match = _POINT_PREFIX.match(path)
            if match:
                _point(msg, int(match.group(1)), topic)
            out[i] = resolve_path(msg, path, topic)
        return out

    return VectorExtractor(names, extract)


def multi_dof_extractor(topic: str, names: tuple[str, ...], first_msg: Any) -> VectorExtractor:
    """control_msgs/MultiDOFCommand by degree-of-freedom name; without names, every value."""
    if not names:
        names = tuple(f"value.{d}" for d in first_msg.dof_names)
    selectors = tuple(_parse(n, _DOF_FIELDS) for n in names)

    def values_of(msg: Any, _point: int, field: str) -> Any:
        return getattr(msg, field)

    by_name = _ByName(topic, "MultiDOFCommand", selectors, lambda m: tuple(m.dof_names), values_of)
    return VectorExtractor(names, by_name)
