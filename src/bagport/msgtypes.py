"""Well-known ROS message type names, named once."""

from __future__ import annotations

from enum import StrEnum

__all__ = ["IMAGE_TYPES", "TF_TYPES", "RosType", "normalize_msgtype"]


class RosType(StrEnum):
    JOINT_STATE = "sensor_msgs/msg/JointState"
    IMAGE = "sensor_msgs/msg/Image"
    COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
    STRING = "std_msgs/msg/String"
    FLOAT32 = "std_msgs/msg/Float32"
    FLOAT64 = "std_msgs/msg/Float64"
    FLOAT32_MULTI_ARRAY = "std_msgs/msg/Float32MultiArray"
    FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
    INT32 = "std_msgs/msg/Int32"
    INT64 = "std_msgs/msg/Int64"
    BOOL = "std_msgs/msg/Bool"
    INT32_MULTI_ARRAY = "std_msgs/msg/Int32MultiArray"
    JOY = "sensor_msgs/msg/Joy"
    JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
    TF_MESSAGE = "tf2_msgs/msg/TFMessage"
    MULTI_DOF_COMMAND = "control_msgs/msg/MultiDOFCommand"
    TF_MESSAGE_ROS1 = "tf/msg/tfMessage"


IMAGE_TYPES = frozenset({RosType.IMAGE.value, RosType.COMPRESSED_IMAGE.value})
TF_TYPES = frozenset({RosType.TF_MESSAGE.value, RosType.TF_MESSAGE_ROS1.value})
"""/tf messages: tf2's, and ROS 1 tf's older ``tf/tfMessage`` (the same fields)."""


def normalize_msgtype(msgtype: str) -> str:
    """``sensor_msgs/Image`` (ROS 1 style) -> ``sensor_msgs/msg/Image``."""
    parts = msgtype.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype.strip()
