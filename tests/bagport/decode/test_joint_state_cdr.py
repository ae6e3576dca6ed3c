"""JointState read from its CDR bytes gives exactly what rosbags' deserialiser gives, or nothing (the
caller then deserialises with rosbags, whose error says what is wrong)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from bagport.bags import BagMessage
from bagport.decode import make_extractor, register_decoder
from bagport.decode.joint_state_cdr import JointStateCdr, joint_state_reader
from bagport.episode.assemble import _decode, _SourceStream

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
JOINT_STATE = "sensor_msgs/msg/JointState"


def _state(
    frame_id: str,
    names: list[str],
    position: list[float],
    velocity: Sequence[float] = (),
    effort: Sequence[float] = (),
) -> Any:
    return T[JOINT_STATE](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=5, nanosec=7), frame_id=frame_id
        ),
        name=names,
        position=np.array(position, dtype=np.float64),
        velocity=np.array(velocity, dtype=np.float64),
        effort=np.array(effort, dtype=np.float64),
    )


def _raw(msg: Any) -> bytes:
    return bytes(TS.serialize_cdr(msg, JOINT_STATE))


def _same(read: Any, msg: Any) -> None:
    assert read is not None
    assert read.name == tuple(msg.name)
    for field in ("position", "velocity", "effort"):
        assert getattr(read, field).tobytes() == np.asarray(getattr(msg, field)).tobytes(), field


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "base", "base_", "base_li", "base_link"])
def test_every_alignment_of_the_arrays_reads_as_rosbags_reads_it(frame_id: str) -> None:
    """The frame id's length moves the names and the doubles through every 4- and 8-byte phase."""
    reader = JointStateCdr()
    for names, values in [(["a", "bb", "ccc"], [1.5, -2.25, 3e300]), (["wrist_roll"], [np.nan])]:
        msg = _state(frame_id, names, values, velocity=[0.5] * len(values))
        _same(reader.read(_raw(msg)), msg)
        _same(reader.read(memoryview(_raw(msg))), msg)  # as MCAP chunks hand them over


def test_alternating_name_orders_are_each_read_with_their_own_names() -> None:
    """Two publishers on one topic (an arm's and a gripper's driver) alternate their name lists."""
    reader = JointStateCdr()
    first = _state("", ["j0", "j1", "j2"], [0.0, 1.0, 2.0], effort=[9.0, 8.0, 7.0])
    second = _state("", ["j2", "j1", "j0"], [2.0, 1.0, 0.0])
    renamed = _state("", ["j0", "j1", "jX"], [0.0, 1.0, 5.0])  # same count, one name differs
    for msg in [first, second, first, second, renamed, first, _state("", [], [4.0, 5.0])]:
        _same(reader.read(_raw(msg)), msg)


def test_bytes_rosbags_refuses_are_not_read() -> None:
    """Every truncation, a missing string terminator, big-endian CDR and trailing bytes: ``None``
    wherever rosbags raises, the same values wherever it reads them."""
    msg = _state("base", ["shoulder", "elbow"], [0.25, -0.5], velocity=[1.0, 2.0], effort=[3.0, 4.0])
    raw = _raw(msg)
    reader = JointStateCdr()
    reader.read(raw)  # its names known: a cut inside them must not pass as a known list
    for cut in range(len(raw)):
        try:
            expected = TS.deserialize_cdr(raw[:cut], JOINT_STATE)
        except Exception:
            assert reader.read(raw[:cut]) is None, cut
        else:
            _same(reader.read(raw[:cut]), expected)
    unterminated = bytearray(raw)
    unterminated[4 + 8 + 4 + 4] = ord("x")  # the NUL after "base"
    assert JointStateCdr().read(bytes(unterminated)) is None
    assert JointStateCdr().read(b"\x00\x00" + raw[2:]) is None  # big-endian encapsulation
    assert JointStateCdr().read(raw + bytes(8)) is None  # rosbags: size mismatch


@dataclass(frozen=True)
class _Src:
    key: str = "observation.state"
    topic: str = "/joint_states"
    msgtype: str = JOINT_STATE
    names: tuple[str, ...] = ("position.elbow", "velocity.shoulder")
    decoder: str | None = None
    child_frame: str | None = None
    parent_frame: str | None = None


def test_the_reader_is_used_only_for_the_built_in_extractor() -> None:
    msg = _state("", ["shoulder", "elbow"], [0.25, -0.5], velocity=[1.0, 2.0])
    raw = _raw(msg)
    assert joint_state_reader(_Src(), make_extractor(_Src(), msg), raw, msg) is not None
    assert joint_state_reader(_Src(), make_extractor(_Src(), msg), None, msg) is None  # a ROS 1 bag
    assert joint_state_reader(_Src(), make_extractor(_Src(), msg), b"\x00\x00" + raw[2:], msg) is None
    custom = _Src(names=(), decoder="tests.bagport.decode.test_joint_state_cdr:stamp_only")
    assert joint_state_reader(custom, make_extractor(custom, msg), raw, msg) is None


def stamp_only(msg: Any, _spec: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    """A user's decoder: reads a field the arrays do not hold."""
    return np.array([msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9])


def test_a_registered_decoder_keeps_the_deserialised_message(monkeypatch: pytest.MonkeyPatch) -> None:
    from bagport.decode import custom  # noqa: PLC0415

    monkeypatch.setattr(custom, "_REGISTRY", dict(custom._REGISTRY))
    register_decoder(JOINT_STATE)(stamp_only)
    msg = _state("", ["shoulder"], [0.25])
    assert joint_state_reader(_Src(names=()), make_extractor(_Src(names=()), msg), _raw(msg), msg) is None


def test_a_stream_deserialises_only_its_first_joint_state() -> None:
    """Pass 2 reads later messages from their bytes (same values), and a damaged one through rosbags
    (whose error the bag reader words as bagport's, ``tests/bagport/bags/test_damage.py``)."""
    stream: Any = _SourceStream.__new__(_SourceStream)
    stream.source, stream.src = _Kind(), _Src()
    stream.extractor, stream.joint_states = None, None
    deserialised: list[int] = []

    def deserialize(raw: bytes | memoryview, msgtype: str) -> Any:
        deserialised.append(len(raw))
        return TS.deserialize_cdr(raw, msgtype)

    def message(msg: Any) -> BagMessage:
        return BagMessage("/joint_states", JOINT_STATE, 0, _raw(msg), deserialize, "cdr")

    msgs = [_state("", ["shoulder", "elbow"], [k, -k], velocity=[2.0 * k, 0.0]) for k in range(5)]
    values = [_decode(stream, message(m)) for m in msgs]
    assert len(deserialised) == 1
    assert [v.tolist() for v in values] == [[-k, 2.0 * k] for k in range(5)]
    damaged = bytearray(_raw(msgs[0]))
    damaged[4 + 16] = 0xFF  # the name count (after the stamp and an empty frame id): beyond the message
    with pytest.raises(SerdeError, match="Invalid sequence length"):  # rosbags' finding (bagport words it)
        _decode(stream, BagMessage("/joint_states", JOINT_STATE, 0, bytes(damaged), deserialize, "cdr"))
    assert len(deserialised) == 2


@dataclass(frozen=True)
class _Kind:
    kind: Any = None
