"""Draft a contract from what a bag contains, for the user to edit (``bagport contract init``)."""

from __future__ import annotations

import re

from bagport.bags.records import BagInfo, TopicInfo
from bagport.msgtypes import IMAGE_TYPES, TF_TYPES, RosType

__all__ = ["draft_contract"]

_ACTION_WORDS = re.compile(r"cmd|command|target|goal|action|leader|desired|setpoint|teleop", re.IGNORECASE)
_TASK_WORDS = re.compile(r"task|prompt|instruction|language|goal_text", re.IGNORECASE)
_BOILERPLATE = {
    *("image_raw", "image", "compressed", "color", "rgb", "image_rect", "image_color", "raw"),
    *("compresseddepth", "ffmpeg", "video"),
}
_ACTION_TYPES = {RosType.JOINT_STATE.value, "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"}
_COMMAND_TYPES = {RosType.JOINT_TRAJECTORY.value, RosType.MULTI_DOF_COMMAND.value}
"""Types that only ever carry commands: an action whatever the topic is called."""


def _camera_name(topic: str, taken: set[str]) -> str:
    parts = [p for p in topic.strip("/").split("/") if p and p.lower() not in _BOILERPLATE]
    base = re.sub(r"[^A-Za-z0-9_]", "_", parts[0] if parts else "camera")
    name, n = base, 2
    while name in taken:
        name, n = f"{base}_{n}", n + 1
    taken.add(name)
    return name


def _entry(key: str, topic: TopicInfo, indent: str = "  ") -> list[str]:
    return [f"{indent}- key: {key}", f"{indent}  topic: {topic.name}", f"{indent}  type: {topic.msgtype}"]


def draft_contract(info: BagInfo, *, robot_type: str = "my_robot", fps: int = 30) -> str:
    """YAML text of a Rosetta-style contract guessed from topic types and names."""
    observations: list[str] = []
    actions: list[str] = []
    tasks: list[str] = []
    unmapped: list[str] = []
    cameras: set[str] = set()
    for topic in info.topics:
        if topic.count == 0:
            unmapped.append(f"#   {topic.name} ({topic.msgtype}): no messages")
        elif topic.msgtype in IMAGE_TYPES:
            observations += _entry(f"observation.images.{_camera_name(topic.name, cameras)}", topic)
        elif topic.msgtype in _COMMAND_TYPES or (
            topic.msgtype in _ACTION_TYPES and _ACTION_WORDS.search(topic.name)
        ):
            actions += [
                "  - key: action",
                "    publish:",
                f"      topic: {topic.name}",
                f"      type: {topic.msgtype}",
            ]
        elif topic.msgtype == RosType.JOINT_STATE:
            observations += _entry("observation.state", topic)
            observations.append(
                "    # selector: {names: [position.<joint>, ...]}  # pin the joints and their order"
            )
        elif topic.msgtype == RosType.STRING and _TASK_WORDS.search(topic.name):
            tasks += _entry("task", topic)
        elif topic.msgtype in TF_TYPES:
            unmapped.append(
                f"#   {topic.name} ({topic.msgtype}): map one transform with selector: {{child_frame: <frame>}}"
            )
        else:
            unmapped.append(f"#   {topic.name} ({topic.msgtype})")
    lines = [
        f"# Drafted by `bagport contract init` from {info.uri}; edit before converting.",
        "# Check it with: bagport contract check <this file> --bag <a bag>",
        f"robot_type: {robot_type}",
        f"fps: {fps}",
        "observations:" if observations else "observations: []",
        *observations,
        "actions:" if actions else "actions: []  # no command topic recognised: map your action topic here",
        *actions,
        "tasks:" if tasks else "tasks: []  # or give each bag a task in the manifest",
        *tasks,
    ]
    if unmapped:
        lines += ["# Not mapped (add them above if the policy needs them):", *unmapped]
    return "\n".join(lines) + "\n"
