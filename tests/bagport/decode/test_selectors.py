"""JointTrajectory selectors, TF child-frame lookups and registered decoders, on rosbags message classes."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from rosbags.typesys import Stores, get_typestore

from bagport.contract import SourceSpec
from bagport.decode import find_transform, make_extractor, register_decoder
from bagport.decode.custom import _REGISTRY
from bagport.errors import ContractError, DecodeError

T = get_typestore(Stores.ROS2_HUMBLE).types
TRAJ = "trajectory_msgs/msg/JointTrajectory"
TF = "tf2_msgs/msg/TFMessage"


def _src(
    msgtype: str,
    names: tuple[str, ...] = (),
    decoder: str | None = None,
    child: str | None = None,
    parent: str | None = None,
) -> SourceSpec:
    return SourceSpec(
        "k", "observations", "/t", msgtype, names, None, "hold", None, None, decoder,
        child_frame=child, parent_frame=parent,
    )  # fmt: skip


def _time() -> Any:
    return T["builtin_interfaces/msg/Time"](sec=1, nanosec=0)


def _header(frame: str = "") -> Any:
    return T["std_msgs/msg/Header"](stamp=_time(), frame_id=frame)


def _point(pos: list[float], vel: list[float], secs: int = 0) -> Any:
    return T["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=np.array(pos),
        velocities=np.array(vel),
        accelerations=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
        time_from_start=T["builtin_interfaces/msg/Duration"](sec=secs, nanosec=0),
    )


def _traj(joints: list[str], points: list[Any]) -> Any:
    return T[TRAJ](header=_header(), joint_names=joints, points=points)


def test_trajectory_first_point_by_default_and_by_name_whatever_the_order() -> None:
    first = _traj(["a", "b"], [_point([1.0, 2.0], [0.1, 0.2]), _point([3.0, 4.0], [0.3, 0.4], 2)])
    ext = make_extractor(_src(TRAJ), first)
    assert ext.names == ("position.a", "position.b")
    assert ext(first).tolist() == [1.0, 2.0]
    swapped = _traj(["b", "a"], [_point([20.0, 10.0], [2.0, 1.0])])
    assert ext(swapped).tolist() == [10.0, 20.0]


def test_trajectory_selectors_points_and_paths() -> None:
    msg = _traj(["a", "b"], [_point([1.0, 2.0], [0.1, 0.2]), _point([3.0, 4.0], [0.3, 0.4], 2)])
    names = ("velocity.b", "points[1].position.a", "points[-1].velocity.a", "b", "positions[1]",
             "points[1].velocities[0]", "points[1].time_from_start.sec")  # fmt: skip
    assert make_extractor(_src(TRAJ, names), msg)(msg).tolist() == [0.2, 3.0, 0.3, 2.0, 2.0, 0.3, 2.0]


def test_trajectory_errors_list_what_exists() -> None:
    msg = _traj(["a", "b"], [_point([1.0, 2.0], [0.1, 0.2])])
    with pytest.raises(
        DecodeError,
        match=r"joint\(s\) \['elbow'\] not in this JointTrajectory message \(it has \['a', 'b'\]\)",
    ):
        make_extractor(_src(TRAJ, ("position.elbow",)), msg)(msg)
    with pytest.raises(DecodeError, match=r"has 1 point\(s\), the selector reads point 3"):
        make_extractor(_src(TRAJ, ("points[3].position.a",)), msg)(msg)
    with pytest.raises(DecodeError, match=r"JointTrajectory\.effort has 0 values for 2 joint names"):
        make_extractor(_src(TRAJ, ("effort.a",)), msg)(msg)
    empty = _traj(["a", "b"], [])
    with pytest.raises(DecodeError, match=r"has 0 point\(s\)"):
        make_extractor(_src(TRAJ), msg)(empty)


def _stamped(parent: str, child: str, x: float) -> Any:
    transform = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
        rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(parent), child_frame_id=child, transform=transform
    )


def test_tf_lookup_by_child_and_parent_frame() -> None:
    msg = T[TF](
        transforms=[
            _stamped("/world", "/tool0", 1.0),
            _stamped("base", "tool0", 2.0),
            _stamped("base", "cam", 3.0),
        ]
    )
    last, from_world = find_transform(msg, "tool0", None), find_transform(msg, "tool0", "world")
    assert last is not None and last.transform.translation.x == 2.0  # the last one
    assert from_world is not None and from_world.transform.translation.x == 1.0  # ROS 1 leading '/' ignored
    assert find_transform(msg, "gripper", None) is None
    ext = make_extractor(_src(TF, child="tool0", parent="world"), msg)
    assert ext.names[0] == "tool0.translation.x"
    assert ext(msg).tolist() == [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    ext = make_extractor(_src(TF, ("translation.x", "rotation.w"), child="cam"), msg)
    assert ext.names == ("cam.translation.x", "cam.rotation.w")
    assert ext(msg).tolist() == [3.0, 1.0]
    with pytest.raises(
        DecodeError,
        match=r"no transform to 'gripper' \(it has \['world -> tool0', 'base -> tool0', 'base -> cam'\]\)",
    ):
        make_extractor(_src(TF, child="gripper"), msg)(msg)


GRIPPER = "acme_msgs/msg/GripperStatus"


def test_registered_decoder_serves_entries_without_their_own() -> None:
    msg = T["std_msgs/msg/Float64"](data=2.0)
    try:

        @register_decoder("std_msgs/Float64")  # ROS 1 spelling is normalised
        def halves(msg: Any, spec: Any) -> npt.NDArray[np.float64]:
            return np.array([msg.data / 2, msg.data / 4])

        ext = make_extractor(_src("std_msgs/msg/Float64"), msg)
        assert ext(msg).tolist() == [1.0, 0.5]
        assert ext.names == ("k_0", "k_1")
        named = make_extractor(_src("std_msgs/msg/Float64", ("half", "quarter")), msg)
        assert named.names == ("half", "quarter")
        own = make_extractor(_src("std_msgs/msg/Float64", decoder=f"{__name__}:triple"), msg)
        assert own(msg).tolist() == [6.0]  # the entry's own decoder wins
    finally:
        _REGISTRY.pop("std_msgs/msg/Float64", None)
    assert make_extractor(_src("std_msgs/msg/Float64"), msg)(msg).tolist() == [2.0]


def triple(msg: Any, spec: Any) -> float:
    return float(msg.data) * 3


def matrix(msg: Any, spec: Any) -> npt.NDArray[np.float64]:
    return np.zeros((2, 2))


def broken(msg: Any, spec: Any) -> float:
    raise KeyError("gain")


def test_decoder_mistakes_are_explained() -> None:
    with pytest.raises(ContractError, match=r"must accept two positional arguments \(msg, spec\)"):

        @register_decoder(GRIPPER)  # type: ignore[arg-type]
        def one_argument(msg: Any) -> float:
            return 0.0

    msg = T["std_msgs/msg/Float64"](data=2.0)
    with pytest.raises(DecodeError, match=r"returned shape \(2, 2\), not a 1-D vector"):
        make_extractor(_src("std_msgs/msg/Float64", decoder=f"{__name__}:matrix"), msg)
    with pytest.raises(
        DecodeError, match=rf"decoder {__name__}:broken failed on a std_msgs/msg/Float64 message \(KeyError"
    ):
        make_extractor(_src("std_msgs/msg/Float64", decoder=f"{__name__}:broken"), msg)


MULTI_DOF = "control_msgs/msg/MultiDOFCommand"
MULTI_DOF_MSG = "string[] dof_names\nfloat64[] values\nfloat64[] values_dot\n"


def test_multi_dof_command_by_dof_name() -> None:
    from rosbags.typesys import get_types_from_msg  # noqa: PLC0415

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(
        get_types_from_msg(MULTI_DOF_MSG, MULTI_DOF)
    )  # not bundled: the bag or --msg-path gives it
    cmd = store.types[MULTI_DOF]
    msg = cmd(dof_names=["x", "yaw"], values=np.array([1.0, 2.0]), values_dot=np.array([0.1, 0.2]))
    ext = make_extractor(_src(MULTI_DOF), msg)
    assert ext.names == ("value.x", "value.yaw")
    assert ext(msg).tolist() == [1.0, 2.0]
    ext = make_extractor(_src(MULTI_DOF, ("value_dot.yaw", "x")), msg)
    swapped = cmd(dof_names=["yaw", "x"], values=np.array([5.0, 4.0]), values_dot=np.array([0.5, 0.4]))
    assert ext(swapped).tolist() == [0.5, 4.0]
    with pytest.raises(DecodeError, match=r"joint\(s\) \['z'\] not in this MultiDOFCommand message"):
        make_extractor(_src(MULTI_DOF, ("z",)), msg)(msg)
