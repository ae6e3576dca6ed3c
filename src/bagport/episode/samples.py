"""Which messages of a topic are the samples of a filtered stream (``SourceSpec.stream_filter``).

A TF stream's samples are the /tf messages carrying its transform; a JointState stream selecting joints
by name takes the messages naming all its joints, so publishers with different joints (an arm's and a
gripper's driver) may share ``/joint_states``. The timeline (pass 1), the replay (pass 2) and the
contract check ask the same question through one :class:`SampleTest` per stream.
"""

from __future__ import annotations

from bagport.bags import BagMessage
from bagport.contract.plan import StreamFilter, TransformFilter
from bagport.decode import child_frames, find_transform, transform_stamp_ns
from bagport.decode.joint_state_cdr import JointStateCdr

__all__ = ["SampleTest", "sample_tests"]

_SEEN_KEPT = 30
"""What other samples a topic had (frames, joint lists), kept for the error when none is the stream's."""
_NAME_LISTS_KEPT = 8


class SampleTest:
    """One filtered stream: whether a message is a sample, its stamp, and what the topic had instead."""

    def __init__(self, spec: StreamFilter) -> None:
        self.spec = spec
        self.seen: dict[str, None] = {}
        """Transforms (``parent -> child``) or joint lists of the messages that were not samples."""
        self._names = JointStateCdr()
        self._recent: list[tuple[tuple[str, ...], bool]] = []
        """The latest name lists (one per publisher, usually) and whether they name the stream's joints."""
        self._joints_seen: set[str] = set()

    def carries(self, message: BagMessage) -> bool:
        """Whether ``message`` (on the filter's topic) is a sample of the stream."""
        if isinstance(self.spec, TransformFilter):
            msg = message.msg()
            if find_transform(msg, self.spec.child_frame, self.spec.parent_frame) is not None:
                return True
            if len(self.seen) < _SEEN_KEPT:
                self.seen.update(dict.fromkeys(child_frames(msg)))
            return False
        return self._names_joints(message, self.spec.joints)

    def stamp_ns(self, message: BagMessage) -> int | None:
        """The sample's header stamp (a transform's own for TF), once :meth:`carries` said yes."""
        if isinstance(self.spec, TransformFilter):
            transform = find_transform(message.msg(), self.spec.child_frame, self.spec.parent_frame)
            return None if transform is None else transform_stamp_ns(transform)
        return message.header_stamp_ns()

    def _names_joints(self, message: BagMessage, joints: tuple[str, ...]) -> bool:
        raw = message.cdr
        names = None if raw is None else self._names.names(raw)
        if names is None:  # ROS 1, big-endian, or bytes rosbags must judge
            names = tuple(message.msg().name)
        for known, carries in self._recent:  # the reader hands back the same tuple for the same names
            if known is names:
                return carries
        carries = set(joints) <= set(names)
        self._joints_seen.update(names)
        if not carries and len(self.seen) < _SEEN_KEPT:
            self.seen[str(list(names))] = None
        self._recent = [(names, carries), *self._recent[: _NAME_LISTS_KEPT - 1]]
        return carries

    def wanted(self) -> str:
        """What a sample carries, for errors: ``a transform to child frame 'tool0'``."""
        if isinstance(self.spec, TransformFilter):
            parent = f" from {self.spec.parent_frame!r}" if self.spec.parent_frame else ""
            return f"a transform to child frame {self.spec.child_frame!r}{parent}"
        return f"all of the joints {list(self.spec.joints)}"

    def seen_text(self) -> str:
        """What the topic's messages had instead; for joints, also those no message names at all."""
        if isinstance(self.spec, TransformFilter):
            return f"transforms seen: {', '.join(self.seen) or 'none'}"
        seen = f"joint lists seen: {', '.join(self.seen) or 'none'}"
        unnamed = [j for j in self.spec.joints if j not in self._joints_seen]
        return f"no message names {unnamed}; {seen}" if unnamed else seen

    def fix(self) -> str:
        if isinstance(self.spec, TransformFilter):
            return "set selector.child_frame (and parent_frame) to a frame the bag publishes."
        if self.seen and not self._joints_seen:
            return "the robot publishes no joint names: select by index, e.g. 'position[0]'."
        return (
            "use joint names the robot publishes in selector.names; when the joints come from different "
            "publishers on the topic (an arm's and a gripper's driver), give each publisher's joints their own "
            "entry with the same key: the entries' values are concatenated in declaration order."
        )

    @property
    def field(self) -> str:
        """The contract field to fix: ``selector.child_frame`` or ``selector.names``."""
        return "selector.child_frame" if isinstance(self.spec, TransformFilter) else "selector.names"


def sample_tests(filters: dict[str, StreamFilter]) -> dict[str, SampleTest]:
    """A test per filtered stream (a stream name -> its test)."""
    return {stream: SampleTest(spec) for stream, spec in filters.items()}
