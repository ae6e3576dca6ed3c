"""Decoders on real rosbags message classes: selection by name/path, colours, errors."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
import simplejpeg
from PIL import Image as PILImage
from rosbags.typesys import Stores, get_typestore

from bagport.contract import SourceSpec
from bagport.decode import decode_image, make_extractor, resize_rgb
from bagport.errors import DecodeError

TS = get_typestore(Stores.ROS2_HUMBLE)
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]
JointState = TS.types["sensor_msgs/msg/JointState"]
Image = TS.types["sensor_msgs/msg/Image"]
CompressedImage = TS.types["sensor_msgs/msg/CompressedImage"]
Float64 = TS.types["std_msgs/msg/Float64"]
Float64MultiArray = TS.types["std_msgs/msg/Float64MultiArray"]
MultiArrayLayout = TS.types["std_msgs/msg/MultiArrayLayout"]
Twist = TS.types["geometry_msgs/msg/Twist"]
Vector3 = TS.types["geometry_msgs/msg/Vector3"]


def _src(msgtype: str, names: tuple[str, ...] = (), decoder: str | None = None) -> SourceSpec:
    return SourceSpec("k", "observations", "/t", msgtype, names, None, "hold", None, None, decoder)


def _header() -> Any:
    return Header(stamp=Time(sec=1, nanosec=2), frame_id="")


def _joint_state(names: list[str], pos: list[float], vel: list[float] | None = None) -> Any:
    return JointState(
        header=_header(),
        name=names,
        position=np.array(pos, dtype=np.float64),
        velocity=np.array(vel if vel is not None else [], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
    )


def test_joint_state_selects_by_name_whatever_the_order() -> None:
    src = _src("sensor_msgs/msg/JointState", ("position.b", "velocity.a", "a"))
    first = _joint_state(["a", "b"], [1.0, 2.0], [10.0, 20.0])
    extractor = make_extractor(src, first)
    assert extractor.names == ("position.b", "velocity.a", "a")
    assert extractor(first).tolist() == [2.0, 10.0, 1.0]
    swapped = _joint_state(["b", "a"], [2.5, 1.5], [25.0, 15.0])
    assert extractor(swapped).tolist() == [2.5, 15.0, 1.5]


def test_joint_state_without_selector_takes_all_positions_in_first_order() -> None:
    first = _joint_state(["x", "y"], [1.0, 2.0])
    extractor = make_extractor(_src("sensor_msgs/msg/JointState"), first)
    assert extractor.names == ("position.x", "position.y")
    assert extractor(_joint_state(["y", "x"], [5.0, 4.0])).tolist() == [4.0, 5.0]


def test_joints_that_another_publisher_on_the_topic_sends_are_said_to_be() -> None:
    """An arm's and a gripper's driver both on /joint_states, and an entry without selector.names (every joint
    of the first message): the gripper's message lacks the arm's joints the first messages had; the error says
    the topic is shared and that naming the joints fixes it (an entry naming its joints reads only the messages
    naming them: tests/bagport/episode/test_samples.py)."""
    arm = _joint_state(["j1", "j2"], [1.0, 2.0])
    extractor = make_extractor(_src("sensor_msgs/msg/JointState"), arm)
    assert extractor(arm).tolist() == [1.0, 2.0]
    with pytest.raises(DecodeError) as caught:
        extractor(_joint_state(["j3"], [0.5]))
    said = str(caught.value)
    assert (
        "joint(s) ['j1', 'j2'] not in this JointState message (it has ['j3']), though earlier messages"
        in said
    )
    assert "Fix: list the joints in selector.names: an entry then reads only the messages naming all" in said
    assert "fix selector.names" not in said
    fresh = make_extractor(_src("sensor_msgs/msg/JointState", ("position.j1",)), arm)
    with pytest.raises(
        DecodeError, match=r"joint names the robot publishes; if other messages on this topic"
    ):
        fresh(
            _joint_state(["j3"], [0.5])
        )  # the first message seen is the other publisher's: both causes said


def test_joint_state_errors_say_what_is_missing() -> None:
    extractor = make_extractor(
        _src("sensor_msgs/msg/JointState", ("position.z",)), _joint_state(["a"], [1.0])
    )
    with pytest.raises(DecodeError, match=r"joint\(s\) \['z'\] not in this JointState message"):
        extractor(_joint_state(["a"], [1.0]))
    extractor = make_extractor(
        _src("sensor_msgs/msg/JointState", ("velocity.a",)), _joint_state(["a"], [1.0])
    )
    with pytest.raises(DecodeError, match=r"velocity has 0 values for 1 joint names"):
        extractor(_joint_state(["a"], [1.0]))


def test_scalars_arrays_and_dot_paths() -> None:
    assert make_extractor(_src("std_msgs/msg/Float64"), Float64(data=2.5))(Float64(data=3.5)).tolist() == [
        3.5
    ]
    arr = Float64MultiArray(layout=MultiArrayLayout(dim=[], data_offset=0), data=np.array([1.0, 2.0, 3.0]))
    ext = make_extractor(_src("std_msgs/msg/Float64MultiArray"), arr)
    assert ext.names == ("data[0]", "data[1]", "data[2]")
    assert ext(arr).tolist() == [1.0, 2.0, 3.0]
    twist = Twist(linear=Vector3(x=1.0, y=2.0, z=3.0), angular=Vector3(x=4.0, y=5.0, z=6.0))
    ext = make_extractor(_src("geometry_msgs/msg/Twist", ("angular.z", "linear.x")), twist)
    assert ext(twist).tolist() == [6.0, 1.0]
    ext = make_extractor(_src("std_msgs/msg/Float64MultiArray", ("data[2]",)), arr)
    assert ext(arr).tolist() == [3.0]
    with pytest.raises(DecodeError, match="has no field 'linar'"):
        make_extractor(_src("geometry_msgs/msg/Twist", ("linar.x",)), twist)(twist)
    log = TS.types["std_msgs/msg/String"](data="x")
    with pytest.raises(DecodeError, match="does not know which fields of std_msgs/msg/String"):
        make_extractor(_src("std_msgs/msg/String"), log)


def double_it(msg: Any, spec: Any) -> npt.NDArray[Any]:
    return np.array([msg.data * 2, msg.data * 3])


def test_custom_decoder() -> None:
    ext = make_extractor(_src("std_msgs/msg/Float64", decoder=f"{__name__}:double_it"), Float64(data=1.0))
    assert ext(Float64(data=2.0)).tolist() == [4.0, 6.0]
    assert ext.names == ("k_0", "k_1")


RGB = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], dtype=np.uint8)  # one row: red, green, blue


def _raw(encoding: str, pixels: npt.NDArray[Any], pad: int = 0) -> Any:
    h, w, c = pixels.shape
    rows = np.zeros((h, w * c + pad), dtype=np.uint8)
    rows[:, : w * c] = pixels.reshape(h, w * c)
    return Image(
        header=_header(),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=w * c + pad,
        data=rows.ravel(),
    )


@pytest.mark.parametrize(
    ("encoding", "pixels"),
    [
        pytest.param("rgb8", RGB, id="rgb8"),
        pytest.param("bgr8", RGB[:, :, ::-1], id="bgr8"),
        pytest.param("rgba8", np.concatenate([RGB, np.full((1, 3, 1), 7, np.uint8)], axis=2), id="rgba8"),
        pytest.param(
            "bgra8", np.concatenate([RGB[:, :, ::-1], np.full((1, 3, 1), 7, np.uint8)], axis=2), id="bgra8"
        ),
    ],
)
def test_raw_images_come_out_rgb(encoding: str, pixels: npt.NDArray[Any]) -> None:
    out = decode_image(_raw(encoding, pixels, pad=4), "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(out, RGB)


def test_mono8_becomes_grey_rgb() -> None:
    out = decode_image(_raw("mono8", np.array([[[10], [20]]], dtype=np.uint8)), "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(out, [[[10, 10, 10], [20, 20, 20]]])


def test_raw_image_errors() -> None:
    with pytest.raises(DecodeError, match=r"encoding .nv21. is not supported"):
        decode_image(_raw("nv21", RGB), "sensor_msgs/msg/Image")
    msg = _raw("rgb8", RGB)
    msg.data = msg.data[:-3]
    with pytest.raises(DecodeError, match="truncated"):
        decode_image(msg, "sensor_msgs/msg/Image")


def test_jpeg_and_png_decode_to_rgb() -> None:
    block = np.repeat(np.repeat(RGB, 16, axis=0), 16, axis=1)  # 16x48, three colour blocks
    jpeg = simplejpeg.encode_jpeg(np.ascontiguousarray(block), quality=95, colorspace="RGB")
    msg = CompressedImage(
        header=_header(), format="rgb8; jpeg compressed bgr8", data=np.frombuffer(jpeg, np.uint8)
    )
    out = decode_image(msg, "sensor_msgs/msg/CompressedImage")
    centres = out[8, [8, 24, 40]].astype(int)
    assert np.abs(centres - RGB[0]).max() < 8
    buf = io.BytesIO()
    PILImage.fromarray(block).save(buf, format="PNG")
    msg = CompressedImage(header=_header(), format="png", data=np.frombuffer(buf.getvalue(), np.uint8))
    np.testing.assert_array_equal(decode_image(msg, "sensor_msgs/msg/CompressedImage"), block)
    bad = CompressedImage(header=_header(), format="jpeg", data=np.frombuffer(b"\xff\xd8garbage", np.uint8))
    with pytest.raises(DecodeError, match="cannot be decoded"):
        decode_image(bad, "sensor_msgs/msg/CompressedImage")


def test_resize_keeps_colours() -> None:
    block = np.repeat(np.repeat(RGB, 20, axis=0), 20, axis=1)
    out = resize_rgb(block, 10, 30)
    assert out.shape == (10, 30, 3)
    np.testing.assert_array_equal(out[5, [5, 15, 25]], RGB[0])


def test_default_fields_for_common_types_like_rosetta() -> None:
    imu = TS.types["sensor_msgs/msg/Imu"](
        header=_header(),
        orientation=TS.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9),
        angular_velocity=Vector3(x=1.0, y=2.0, z=3.0),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=Vector3(x=4.0, y=5.0, z=9.81),
        linear_acceleration_covariance=np.zeros(9),
    )
    ext = make_extractor(_src("sensor_msgs/msg/Imu"), imu)
    assert ext.names[:4] == ("orientation.x", "orientation.y", "orientation.z", "orientation.w")
    assert ext(imu).tolist() == [0.0, 0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 4.0, 5.0, 9.81]
    twist = Twist(linear=Vector3(x=1.0, y=2.0, z=3.0), angular=Vector3(x=4.0, y=5.0, z=6.0))
    assert make_extractor(_src("geometry_msgs/msg/Twist"), twist)(twist).tolist() == [1, 2, 3, 4, 5, 6]
    joy = TS.types["sensor_msgs/msg/Joy"](
        header=_header(), axes=np.array([0.5, -0.5], np.float32), buttons=np.array([1, 0, 1], np.int32)
    )
    ext = make_extractor(_src("sensor_msgs/msg/Joy"), joy)
    assert ext.names == ("axes[0]", "axes[1]", "buttons[0]", "buttons[1]", "buttons[2]")
    assert ext(joy).tolist() == [0.5, -0.5, 1.0, 0.0, 1.0]
