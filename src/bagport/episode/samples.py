"""Which messages of a topic are the samples of a filtered stream (``SourceSpec.stream_filter``).

A TF stream's samples are the /tf messages carrying its transform; a JointState stream selecting joints
by name takes the messages naming all its joints, so publishers with different joints (an arm's and a
gripper's driver) may share ``/joint_states``; a camera's are its images with pixels. The timeline (pass 1), the replay (pass 2) and the
contract check ask the same question through one :class:`SampleTest` per stream.
"""

from __future__ import annotations

from bagport.bags import BagMessage
from bagport.contract.plan import ImageFilter, JointFilter, StreamFilter, TransformFilter
from bagport.decode import child_frames, find_transform, transform_stamp_ns
from bagport.decode.joint_state_cdr import JointStateCdr

__all__ = ["MIXED_JOINT_LISTS_FIX", "JointListGuard", "SampleTest", "mixed_joint_lists", "sample_tests"]

_SEEN_KEPT = 30
"""What other samples a topic had (frames, joint lists), kept for the error when none is the stream's."""
_NAME_LISTS_KEPT = 8


class SampleTest:
    """One filtered stream: whether a message is a sample, its stamp, and what the topic had instead."""

    field = "selector.names"
    """The contract field to fix when no message is a sample."""

    def __init__(self, spec: StreamFilter) -> None:
        self.spec = spec
        self.seen: dict[str, None] = {}
        """What the messages that were not samples had instead (transforms, joint lists)."""

    def carries(self, message: BagMessage) -> bool:
        """Whether ``message`` (on the filter's topic) is a sample of the stream."""
        raise NotImplementedError

    def stamp_ns(self, message: BagMessage) -> int | None:
        """The sample's header stamp, once :meth:`carries` said yes."""
        return message.header_stamp_ns()

    def wanted(self) -> str:
        """What a sample carries, for errors: ``a transform to child frame 'tool0'``."""
        raise NotImplementedError

    def seen_text(self) -> str:
        """What the topic's messages had instead, for errors."""
        raise NotImplementedError

    def fix(self) -> str:
        raise NotImplementedError


class _TransformTest(SampleTest):
    field = "selector.child_frame"

    def __init__(self, spec: TransformFilter) -> None:
        super().__init__(spec)
        self._child, self._parent = spec.child_frame, spec.parent_frame

    def carries(self, message: BagMessage) -> bool:
        msg = message.msg()
        if find_transform(msg, self._child, self._parent) is not None:
            return True
        if len(self.seen) < _SEEN_KEPT:
            self.seen.update(dict.fromkeys(child_frames(msg)))
        return False

    def stamp_ns(self, message: BagMessage) -> int | None:
        """The transform's own header stamp."""
        transform = find_transform(message.msg(), self._child, self._parent)
        return None if transform is None else transform_stamp_ns(transform)

    def wanted(self) -> str:
        parent = f" from {self._parent!r}" if self._parent else ""
        return f"a transform to child frame {self._child!r}{parent}"

    def seen_text(self) -> str:
        return f"transforms seen: {', '.join(self.seen) or 'none'}"

    def fix(self) -> str:
        return "set selector.child_frame (and parent_frame) to a frame the bag publishes."


class _JointTest(SampleTest):
    def __init__(self, spec: JointFilter) -> None:
        super().__init__(spec)
        self._joints = spec.joints
        self._reader = JointStateCdr()
        self._last: tuple[tuple[str, ...] | None, bool] = (None, False)
        self._recent: list[tuple[tuple[str, ...], bool]] = []
        """The latest name lists (one per publisher, usually) and whether they name the stream's joints."""
        self._joints_seen: set[str] = set()

    def carries(self, message: BagMessage) -> bool:
        names = self._reader.names_of(message)
        last_names, last_carries = self._last
        if names is last_names:  # the reader hands back the same tuple for the same names
            return last_carries
        carries = next((c for known, c in self._recent if known is names), None)
        if carries is None:
            carries = set(self._joints) <= set(names)
            self._joints_seen.update(names)
            if not carries and len(self.seen) < _SEEN_KEPT:
                self.seen[str(list(names))] = None
            self._recent = [(names, carries), *self._recent[: _NAME_LISTS_KEPT - 1]]
        self._last = (names, carries)
        return carries

    def wanted(self) -> str:
        return f"all of the joints {list(self._joints)}"

    def seen_text(self) -> str:
        """The joint lists seen, and the joints no message names at all."""
        seen = f"joint lists seen: {', '.join(self.seen) or 'none'}"
        unnamed = [j for j in self._joints if j not in self._joints_seen]
        return f"no message names {unnamed}; {seen}" if unnamed else seen

    def fix(self) -> str:
        if self.seen and not self._joints_seen:
            return "the robot publishes no joint names: select by index, e.g. 'position[0]'."
        return (
            "use joint names the robot publishes in selector.names; when the joints come from different "
            "publishers on the topic (an arm's and a gripper's driver), give each publisher's joints their own "
            "entry with the same key: the entries' values are concatenated in declaration order."
        )


class _ImageTest(SampleTest):
    """A camera's messages with pixels (drivers publish empty images before their first frame)."""

    field = "topic"

    def __init__(self, spec: ImageFilter) -> None:
        super().__init__(spec)
        self._compressed = spec.compressed
        self.empty = 0

    def carries(self, message: BagMessage) -> bool:
        if self._compressed:  # format, then the data's length
            size = message.fields_after_header("I", strings=1) or (len(message.msg().data),)
        else:  # height, width
            size = message.fields_after_header("II") or (int(message.msg().height), int(message.msg().width))
        if all(size):
            return True
        self.empty += 1
        return False

    def wanted(self) -> str:
        return "an image with pixels"

    def seen_text(self) -> str:
        return f"{self.empty} empty image(s)"

    def fix(self) -> str:
        return (
            "the camera published no frame in this bag or window: check the camera, or leave the topic out."
        )


def sample_tests(filters: dict[str, StreamFilter]) -> dict[str, SampleTest]:
    """A test per filtered stream (a stream name -> its test)."""
    return {stream: _test(spec) for stream, spec in filters.items()}


def _test(spec: StreamFilter) -> SampleTest:
    if isinstance(spec, TransformFilter):
        return _TransformTest(spec)
    if isinstance(spec, JointFilter):
        return _JointTest(spec)
    return _ImageTest(spec)


class JointListGuard:
    """A JointState topic an entry reads by index alone (``position[0]``): its messages must all name the same
    joints in the same order, or the entry would mix two publishers' arrays without a sign."""

    def __init__(self) -> None:
        self._reader = JointStateCdr()
        self._first: tuple[str, ...] | None = None

    def other_list(self, message: BagMessage) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
        """``(the first message's names, this one's)`` when they differ, else ``None``."""
        names = self._reader.names_of(message)
        if self._first is None:
            self._first = names
        elif names is not self._first and names != self._first:
            return self._first, names
        return None


def mixed_joint_lists(topic: str, first: tuple[str, ...], other: tuple[str, ...], entry: str) -> str:
    """What is wrong with an entry reading ``topic`` by index alone when its messages name different joints."""
    return (
        f"{topic} carries messages naming different joints ({list(first)}, then {list(other)}): publishers with "
        f"different joints share it, and the entry ({entry}) selects by index, which would mix their arrays"
    )


MIXED_JOINT_LISTS_FIX = (
    "select the joints by name in selector.names (an entry then reads only the messages naming them); give "
    "each publisher's joints an entry of their own with the same key."
)
