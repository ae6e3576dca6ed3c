"""Draft a contract from what a bag contains, for the user to edit (``bagport contract init``)."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence

from bagport.bags import BagReader
from bagport.bags.records import BagInfo, TopicInfo
from bagport.decode.joint_state_cdr import joint_lists
from bagport.msgtypes import IMAGE_TYPES, TF_TYPES, RosType

__all__ = ["draft_contract", "draft_contract_from_bag"]

_JOINT_MESSAGES_READ = 400
"""Messages read per JointState topic to find its publishers' joint lists (each publishes at every cycle)."""

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


def draft_contract_from_bag(reader: BagReader, *, robot_type: str = "my_robot", fps: int = 30) -> str:
    """:func:`draft_contract` of an open bag, its JointState entries naming the joints each publisher sends."""
    topics = [t.name for t in reader.info.topics if t.msgtype == RosType.JOINT_STATE and t.count]
    joints = joint_lists(reader, topics, _JOINT_MESSAGES_READ)
    return draft_contract(reader.info, robot_type=robot_type, fps=fps, joints=joints)


def _joint_entries(key: str, topic: TopicInfo, lists: Sequence[tuple[str, ...]]) -> list[str]:
    """A JointState entry per joint list (one per publisher on the topic), or one naming no joints."""
    named = [names for names in lists if names]
    if not named:
        return [
            *_entry(key, topic),
            "    # selector: {names: [position.<joint>, ...]}  # pin the joints and their order",
        ]
    lines = []
    if len(named) > 1:
        lines.append(
            f"  # {topic.name} carries {len(named)} joint lists (publishers sharing it): an entry each, same key"
        )
    for names in named:
        selected = [f"position.{name}" for name in names]  # the joint's position, whatever dots its name has
        lines += [*_entry(key, topic), f"    selector: {{names: {json.dumps(selected)}}}"]
    return lines


def draft_contract(
    info: BagInfo,
    *,
    robot_type: str = "my_robot",
    fps: int = 30,
    joints: Mapping[str, Sequence[tuple[str, ...]]] | None = None,
) -> str:
    """YAML text of a Rosetta-style contract guessed from topic types and names; ``joints`` (see
    :func:`bagport.decode.joint_state_cdr.joint_lists`) names the joints of JointState state entries."""
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
            observations += _joint_entries("observation.state", topic, (joints or {}).get(topic.name, []))
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
