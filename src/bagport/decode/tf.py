"""tf2_msgs/TFMessage lookups: one named transform out of the many a /tf message carries.

A contract entry names the transform by ``selector.child_frame`` (and optionally
``selector.parent_frame``); only /tf messages that contain it are samples of the feature, and its
own ``header.stamp`` is the sample's header stamp.  Frame ids are compared without a leading ``/``
(ROS 1 tf wrote ``/base_link``).
"""

from __future__ import annotations

from typing import Any

from bagport.decode.paths import VectorExtractor, paths_extractor
from bagport.errors import DecodeError

__all__ = ["TF_FIELDS", "child_frames", "find_transform", "tf_extractor", "transform_stamp_ns"]

TF_FIELDS = (
    "translation.x",
    "translation.y",
    "translation.z",
    "rotation.x",
    "rotation.y",
    "rotation.z",
    "rotation.w",
)
"""Default dimensions of a TF lookup, relative to the transform (``geometry_msgs/Transform``)."""


def _frame(frame_id: str) -> str:
    return frame_id.lstrip("/")


def find_transform(msg: Any, child_frame: str, parent_frame: str | None) -> Any | None:
    """The last ``geometry_msgs/TransformStamped`` in ``msg`` for this child (and parent) frame."""
    child = _frame(child_frame)
    parent = _frame(parent_frame) if parent_frame is not None else None
    for transform in reversed(msg.transforms):
        if _frame(transform.child_frame_id) != child:
            continue
        if parent is None or _frame(transform.header.frame_id) == parent:
            return transform
    return None


def child_frames(msg: Any) -> list[str]:
    """``parent -> child`` of every transform in ``msg``, for error messages."""
    return [f"{_frame(t.header.frame_id)} -> {_frame(t.child_frame_id)}" for t in msg.transforms]


def transform_stamp_ns(transform: Any) -> int:
    stamp = transform.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def tf_extractor(
    topic: str, names: tuple[str, ...], child_frame: str, parent_frame: str | None
) -> VectorExtractor:
    """Translation and rotation (or the named fields of the transform) of ``child_frame``; the
    dimension names are prefixed with the frame (``tool0.translation.x``)."""
    paths = names or TF_FIELDS
    inner = paths_extractor(topic, paths)

    def extract(msg: Any) -> Any:
        transform = find_transform(msg, child_frame, parent_frame)
        if transform is None:
            raise DecodeError(
                f"this TFMessage has no transform to {child_frame!r} (it has {child_frames(msg)})",
                topic=topic,
                fix="check selector.child_frame / parent_frame.",
            )
        return inner(transform.transform)

    return VectorExtractor(tuple(f"{_frame(child_frame)}.{p}" for p in paths), extract)
