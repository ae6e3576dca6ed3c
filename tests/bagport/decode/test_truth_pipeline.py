"""Every numeric decoder through the whole pipeline, in each storage format (MCAP, SQLite, ROS 1): a bag
with known values -> convert -> LeRobot loads the dataset -> the values are the ones written."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bagport.config import ConvertConfig
from bagport.contract import parse_contract
from bagport.dataset.validate import validate_dataset
from bagport.feature_table import describe_features
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from tests.bagport.decode.bagwriter import Stream, write_bag

pytestmark = pytest.mark.slow

TS = get_typestore(Stores.ROS2_HUMBLE)
# Not a bundled type: the MCAP bag embeds its definition, which is where the reader gets it.
TS.register(
    get_types_from_msg(
        "string[] dof_names\nfloat64[] values\nfloat64[] values_dot\n", "control_msgs/msg/MultiDOFCommand"
    )
)
T = TS.types
FPS = 10
FRAMES = 12
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 1_000_000_000 // FPS


def _header(t_ns: int, frame: str = "base") -> Any:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=frame
    )


def _vec3(x: float, y: float, z: float) -> Any:
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def _quat(v: float) -> Any:
    return T["geometry_msgs/msg/Quaternion"](x=v, y=v + 0.01, z=v + 0.02, w=v + 0.03)


def _pose(v: float) -> Any:
    return T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=v, y=v + 1, z=v + 2), orientation=_quat(v)
    )


def _twist(v: float) -> Any:
    return T["geometry_msgs/msg/Twist"](linear=_vec3(v, v + 1, v + 2), angular=_vec3(v + 3, v + 4, v + 5))


def _layout() -> Any:
    return T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)


def _cov(n: int) -> Any:
    return np.zeros(n, dtype=np.float64)


def _point(k: int, offset: float) -> Any:
    return T["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=np.array([k + offset, k + offset + 0.5]),
        velocities=np.array([-k - offset, -k - offset - 0.5]),
        accelerations=np.array([], dtype=np.float64),
        effort=np.array([10 * k + offset, 10 * k + offset + 1]),
        time_from_start=T["builtin_interfaces/msg/Duration"](sec=int(offset), nanosec=0),
    )


def _tf(t_ns: int, child: str, v: float) -> Any:
    stamped = T["geometry_msgs/msg/TransformStamped"](
        header=_header(t_ns, "base"),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=_vec3(v, v + 1, v + 2), rotation=_quat(v)),
    )
    return T["tf2_msgs/msg/TFMessage"](transforms=[stamped])


# (topic, type, message for frame k at t_ns, contract extra, expected vector for frame k)
Case = tuple[str, str, Callable[[int, int], Any], str, Callable[[int], list[float]]]


def _q(v: float) -> list[float]:
    return [v, v + 0.01, v + 0.02, v + 0.03]


def _p(v: float) -> list[float]:
    return [v, v + 1, v + 2, *_q(v)]


def _t(v: float) -> list[float]:
    return [v, v + 1, v + 2, v + 3, v + 4, v + 5]


CASES: dict[str, Case] = {
    "twist": ("/cmd_vel", "geometry_msgs/msg/Twist", lambda k, t: _twist(k), "", _t),
    "twist_stamped": (
        "/twist",
        "geometry_msgs/msg/TwistStamped",
        lambda k, t: T["geometry_msgs/msg/TwistStamped"](header=_header(t), twist=_twist(k + 0.5)),
        "",
        lambda k: _t(k + 0.5),
    ),
    "odom": (
        "/odom",
        "nav_msgs/msg/Odometry",
        lambda k, t: T["nav_msgs/msg/Odometry"](
            header=_header(t),
            child_frame_id="base",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(k), covariance=_cov(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=_twist(2 * k), covariance=_cov(36)),
        ),
        "",
        lambda k: _p(k) + _t(2 * k),
    ),
    "imu": (
        "/imu",
        "sensor_msgs/msg/Imu",
        lambda k, t: T["sensor_msgs/msg/Imu"](
            header=_header(t),
            orientation=_quat(k),
            orientation_covariance=_cov(9),
            angular_velocity=_vec3(k, -k, 2 * k),
            angular_velocity_covariance=_cov(9),
            linear_acceleration=_vec3(0.5 * k, 9.81, -k),
            linear_acceleration_covariance=_cov(9),
        ),
        "",
        lambda k: [*_q(k), k, -k, 2 * k, 0.5 * k, 9.81, -k],
    ),
    "joy": (
        "/joy",
        "sensor_msgs/msg/Joy",
        lambda k, t: T["sensor_msgs/msg/Joy"](
            header=_header(t),
            axes=np.array([0.1 * k, -0.25], np.float32),
            buttons=np.array([k % 2, 1], np.int32),
        ),
        "",
        lambda k: [float(np.float32(0.1 * k)), -0.25, k % 2, 1],
    ),
    "joy_selected": (
        "/joy",
        "sensor_msgs/msg/Joy",
        lambda k, t: None,  # same topic as "joy"
        "selector: {names: ['buttons[0]', 'axes[1]']}",
        lambda k: [k % 2, -0.25],
    ),
    "pose_stamped": (
        "/pose",
        "geometry_msgs/msg/PoseStamped",
        lambda k, t: T["geometry_msgs/msg/PoseStamped"](header=_header(t), pose=_pose(3 * k)),
        "",
        lambda k: _p(3 * k),
    ),
    "pose": ("/pose_plain", "geometry_msgs/msg/Pose", lambda k, t: _pose(-k), "", lambda k: _p(-k)),
    "wrench": (
        "/wrench",
        "geometry_msgs/msg/WrenchStamped",
        lambda k, t: T["geometry_msgs/msg/WrenchStamped"](
            header=_header(t),
            wrench=T["geometry_msgs/msg/Wrench"](
                force=_vec3(k, k + 1, k + 2), torque=_vec3(-k, -k - 1, -k - 2)
            ),
        ),
        "",
        lambda k: [k, k + 1, k + 2, -k, -k - 1, -k - 2],
    ),
    "trajectory": (
        "/arm_traj",
        "trajectory_msgs/msg/JointTrajectory",
        lambda k, t: T["trajectory_msgs/msg/JointTrajectory"](
            header=_header(t),
            joint_names=["j1", "j2"] if k % 2 else ["j2", "j1"],
            points=[_point(k, 0.0), _point(k, 100.0)]
            if k % 2
            else [_swap(_point(k, 0.0)), _swap(_point(k, 100.0))],
        ),
        "",
        lambda k: [k, k + 0.5],
    ),
    "trajectory_selected": (
        "/arm_traj",
        "trajectory_msgs/msg/JointTrajectory",
        lambda k, t: None,
        "selector: {names: [velocity.j2, 'points[1].position.j1', 'points[-1].effort.j2', j1]}",
        lambda k: [-k - 0.5, k + 100, 10 * k + 101, k],
    ),
    "tf_tool": (
        "/tf",
        "tf2_msgs/msg/TFMessage",
        lambda k, t: None,  # written below: tool0 and camera transforms in separate messages
        "selector: {child_frame: tool0, parent_frame: base}",
        lambda k: _p(5 * k),
    ),
    "multi_dof": (
        "/dof_cmd",
        "control_msgs/msg/MultiDOFCommand",
        lambda k, t: T["control_msgs/msg/MultiDOFCommand"](
            dof_names=["x", "yaw"], values=np.array([k, -k / 2]), values_dot=np.array([0.1, 0.2])
        ),
        "selector: {names: [yaw, value_dot.x]}",
        lambda k: [-k / 2, 0.1],
    ),
    "f32": (
        "/f32",
        "std_msgs/msg/Float32",
        lambda k, t: T["std_msgs/msg/Float32"](data=np.float32(k / 4)),
        "",
        lambda k: [k / 4],
    ),
    "f64": (
        "/f64",
        "std_msgs/msg/Float64",
        lambda k, t: T["std_msgs/msg/Float64"](data=k / 3),
        "",
        lambda k: [k / 3],
    ),
    "i32": (
        "/i32",
        "std_msgs/msg/Int32",
        lambda k, t: T["std_msgs/msg/Int32"](data=-7 * k),
        "",
        lambda k: [-7 * k],
    ),
    "i64": (
        "/i64",
        "std_msgs/msg/Int64",
        lambda k, t: T["std_msgs/msg/Int64"](data=2**40 + k),
        "",
        lambda k: [2**40 + k],
    ),
    "flag": (
        "/flag",
        "std_msgs/msg/Bool",
        lambda k, t: T["std_msgs/msg/Bool"](data=bool(k % 3 == 0)),
        "",
        lambda k: [k % 3 == 0],
    ),
    "f32_array": (
        "/f32a",
        "std_msgs/msg/Float32MultiArray",
        lambda k, t: T["std_msgs/msg/Float32MultiArray"](
            layout=_layout(), data=np.array([k, 0.5, -k], np.float32)
        ),
        "",
        lambda k: [k, 0.5, -k],
    ),
    "f64_array": (
        "/f64a",
        "std_msgs/msg/Float64MultiArray",
        lambda k, t: T["std_msgs/msg/Float64MultiArray"](layout=_layout(), data=np.array([k / 7, 1e-3])),
        "",
        lambda k: [k / 7, 1e-3],
    ),
    "i32_array": (
        "/i32a",
        "std_msgs/msg/Int32MultiArray",
        lambda k, t: T["std_msgs/msg/Int32MultiArray"](
            layout=_layout(), data=np.array([k, -k, 99], np.int32)
        ),
        "",
        lambda k: [k, -k, 99],
    ),
}


def _swap(point: Any) -> Any:
    """The same point with the joints listed in the other order (j2, j1)."""
    return T["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=point.positions[::-1].copy(),
        velocities=point.velocities[::-1].copy(),
        accelerations=point.accelerations,
        effort=point.effort[::-1].copy(),
        time_from_start=point.time_from_start,
    )


def _streams() -> list[Stream]:
    ticks = [START_NS + k * PERIOD_NS for k in range(FRAMES)]
    written: dict[str, Stream] = {}
    for topic, msgtype, make, _, _ in CASES.values():
        if topic in written or topic == "/tf":
            continue
        written[topic] = (topic, msgtype, [(t, make(k, t)) for k, t in enumerate(ticks)])
    tf: list[tuple[int, Any]] = []
    for k, t in enumerate(ticks):
        tf.append((t, _tf(t, "tool0", 5 * k)))
        tf.append((t + PERIOD_NS // 2, _tf(t + PERIOD_NS // 2, "camera", -1000.0 - k)))  # not a sample
    written["/tf"] = ("/tf", "tf2_msgs/msg/TFMessage", tf)
    task = [(START_NS, T["std_msgs/msg/String"](data="pick the cube"))]
    written["/task"] = ("/task", "std_msgs/msg/String", task)
    return list(written.values())


def _contract() -> str:
    lines = ["robot_type: truth_bot", f"fps: {FPS}", "observations:"]
    for name, (topic, msgtype, _, extra, _) in CASES.items():
        lines.append(f"  - key: observation.{name}")
        lines.append(f"    topic: {topic}")
        lines.append(f"    type: {msgtype}")
        lines.append("    dtype: float64")
        lines.append("    align: {strategy: hold, stamp: receive}")
        if extra:
            lines.append(f"    {extra}")
    lines += ["tasks:", "  - {topic: /task, type: std_msgs/msg/String}"]
    return "\n".join(lines) + "\n"


def _convert(bag: Path, tmp_path: Path, **options: Any) -> Path:
    contract = tmp_path / "contract.yaml"
    contract.write_text(_contract())
    out = tmp_path / "dataset"
    config = ConvertConfig(
        bags_glob=str(bag),
        contract=str(contract),
        output=str(out),
        staging=str(tmp_path / "staging"),
        on_qa_fail="keep",
        **options,
    )
    plan = plan_run(config)
    staged = stage_all(plan)
    reduce_run(plan, staged)
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_every_decoder_matches_the_values_written(
    tmp_path: Path, storage: Literal["mcap", "sqlite3", "ros1"]
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = write_bag(tmp_path / "truth", storage, TS, _streams())
    rows = {row.key: row for row in describe_features(parse_contract(_contract(), "c.yaml"), str(bag))}
    assert rows["observation.tf_tool"].names == tuple(
        f"tool0.{p}"
        for p in (
            "translation.x",
            "translation.y",
            "translation.z",
            "rotation.x",
            "rotation.y",
            "rotation.z",
            "rotation.w",
        )
    )
    assert rows["observation.trajectory"].names == ("position.j2", "position.j1")  # first message's order
    out = _convert(bag, tmp_path)
    assert validate_dataset(out, repo_id="test/truth").frames == FRAMES  # LeRobot v3.0 invariants hold
    dataset = LeRobotDataset("test/truth", root=out)
    assert dataset.meta.total_frames == FRAMES
    assert dataset[0]["task"] == "pick the cube"
    names = {key: feature["names"] for key, feature in dataset.meta.features.items()}
    assert names["observation.trajectory_selected"] == [
        "velocity.j2",
        "points[1].position.j1",
        "points[-1].effort.j2",
        "j1",
    ]
    for name, (*_, expected) in CASES.items():
        got = np.stack([dataset[k][f"observation.{name}"].numpy().reshape(-1) for k in range(FRAMES)])
        want = np.array([expected(k) for k in range(FRAMES)], dtype=np.float64)
        if name == "trajectory":  # the feature's order is fixed by the first message: j2, j1
            want = want[:, ::-1]
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6, err_msg=name)
