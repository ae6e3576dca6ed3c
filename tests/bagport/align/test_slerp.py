"""Quaternion groups and slerp, against analytic rotations."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from hypothesis import given
from hypothesis import strategies as st

from bagport.align import blend, quaternion_groups, slerp

Float = npt.NDArray[np.float64]


def _rotation(axis: Float, angle: float) -> Float:
    """Unit quaternion (x, y, z, w) of ``angle`` rad about ``axis``."""
    unit = axis / np.linalg.norm(axis)
    return np.array([*(unit * np.sin(angle / 2)), np.cos(angle / 2)])


def test_groups_found_by_name_in_rosetta_default_fields() -> None:
    pose = ["pose.position.x", "pose.position.y", "pose.position.z"]
    pose += ["pose.orientation.x", "pose.orientation.y", "pose.orientation.z", "pose.orientation.w"]
    assert quaternion_groups(pose) == ((3, 4, 5, 6),)
    imu = ["orientation.w", "orientation.x", "orientation.y", "orientation.z", "angular_velocity.x"]
    assert quaternion_groups(imu) == ((1, 2, 3, 0),)  # stored x, y, z, w whatever the selector order
    assert quaternion_groups(["x", "y", "z", "w"]) == ((0, 1, 2, 3),)
    assert quaternion_groups(["linear.x", "linear.y", "linear.z", "position.j1"]) == ()
    assert quaternion_groups(["a.x", "a.y", "a.z", "b.w"]) == ()


axes = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
    lambda v: float(np.linalg.norm(v)) > 0.1
)


@given(
    axis=axes,
    omega=st.floats(-3.0, 3.0),
    t0=st.floats(-2.0, 2.0),
    dt=st.floats(0.001, 0.5),
    weight=st.floats(0.0, 1.0),
    flip=st.booleans(),
)
def test_slerp_is_exact_for_a_constant_rate_rotation(
    axis: tuple[float, float, float], omega: float, t0: float, dt: float, weight: float, flip: bool
) -> None:
    a = np.array(axis)
    q0, q1 = _rotation(a, omega * t0), _rotation(a, omega * (t0 + dt))
    if flip:  # -q is the same rotation: slerp must take the short way anyway
        q1 = -q1
    got = slerp(q0, q1, weight)
    truth = _rotation(a, omega * (t0 + weight * dt))
    assert abs(np.linalg.norm(got) - 1.0) < 1e-9
    # q and -q are the same rotation
    assert min(np.abs(got - truth).max(), np.abs(got + truth).max()) < 1e-7


def test_slerp_beats_linear_blending_between_distant_samples() -> None:
    axis = np.array([0.0, 0.0, 1.0])
    q0, q1 = _rotation(axis, 0.0), _rotation(axis, 1.5)
    truth = _rotation(axis, 0.75)
    linear = 0.5 * q0 + 0.5 * q1
    assert np.abs(linear - truth).max() > 0.03  # not unit length, so not a rotation
    np.testing.assert_allclose(slerp(q0, q1, 0.5), truth, atol=1e-12)


def test_blend_slerps_the_quaternion_and_interpolates_the_rest_linearly() -> None:
    axis = np.array([1.0, 1.0, 0.0])
    lo = np.array([0.0, 1.0, 2.0, *_rotation(axis, 0.2)])
    hi = np.array([1.0, 3.0, 2.0, *_rotation(axis, 1.4)])
    out = blend(lo.copy(), hi, 0.25, quaternion_groups(["p.x", "p.y", "p.z", "q.x", "q.y", "q.z", "q.w"]))
    np.testing.assert_allclose(out[:3], [0.25, 1.5, 2.0])
    np.testing.assert_allclose(out[3:], _rotation(axis, 0.5), atol=1e-12)
    np.testing.assert_allclose(blend(lo, hi, 0.25), 0.75 * lo + 0.25 * hi)


def test_an_all_zero_quaternion_blends_linearly_instead_of_nan() -> None:
    """Imu messages without an orientation estimate carry (0, 0, 0, 0)."""
    zero = np.zeros(4)
    np.testing.assert_array_equal(slerp(zero, zero, 0.3), zero)
    unit = np.array([0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(slerp(zero, unit, 0.25), 0.25 * unit)
