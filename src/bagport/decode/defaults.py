"""The fields bagport takes from common message types when a contract gives no selector.

Rosetta's auto features for these types, as dot paths, so its contracts work unchanged.
"""

from __future__ import annotations

__all__ = ["DEFAULT_FIELDS"]

_XYZ = ("x", "y", "z")
_XYZW = ("x", "y", "z", "w")


def _paths(prefix: str, fields: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"{prefix}.{name}" for name in fields)


def _pose(prefix: str) -> tuple[str, ...]:
    return _paths(f"{prefix}.position", _XYZ) + _paths(f"{prefix}.orientation", _XYZW)


def _twist(prefix: str) -> tuple[str, ...]:
    return _paths(f"{prefix}.linear", _XYZ) + _paths(f"{prefix}.angular", _XYZ)


DEFAULT_FIELDS: dict[str, tuple[str, ...]] = {
    "geometry_msgs/msg/Vector3": _XYZ,
    "geometry_msgs/msg/Vector3Stamped": _paths("vector", _XYZ),
    "geometry_msgs/msg/Point": _XYZ,
    "geometry_msgs/msg/Quaternion": _XYZW,
    "geometry_msgs/msg/Pose": _paths("position", _XYZ) + _paths("orientation", _XYZW),
    "geometry_msgs/msg/PoseStamped": _pose("pose"),
    "geometry_msgs/msg/Twist": _paths("linear", _XYZ) + _paths("angular", _XYZ),
    "geometry_msgs/msg/TwistStamped": _twist("twist"),
    "geometry_msgs/msg/Wrench": _paths("force", _XYZ) + _paths("torque", _XYZ),
    "geometry_msgs/msg/WrenchStamped": _paths("wrench.force", _XYZ) + _paths("wrench.torque", _XYZ),
    "nav_msgs/msg/Odometry": _pose("pose.pose") + _twist("twist.twist"),
    "sensor_msgs/msg/Imu": _paths("orientation", _XYZW)
    + _paths("angular_velocity", _XYZ)
    + _paths("linear_acceleration", _XYZ),
}
