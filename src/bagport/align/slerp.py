"""Interpolation of a feature's values between two messages: linear, and slerp for quaternions.

A quaternion is recognised by its dimension names: four names ``<prefix>.x``, ``<prefix>.y``,
``<prefix>.z``, ``<prefix>.w`` (or bare ``x, y, z, w``), as selectors and Rosetta's default fields
name ``Pose``, ``Imu``, ``Odometry``, ``Transform`` and ``Quaternion`` orientations.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ["QuaternionGroup", "blend", "quaternion_groups", "slerp"]

FloatArray = npt.NDArray[np.float64]
QuaternionGroup = tuple[int, int, int, int]
"""Indices of x, y, z, w inside a feature vector."""

_XYZW = ("x", "y", "z", "w")
_NEARLY_PARALLEL = 1.0 - 1e-9


def quaternion_groups(names: Sequence[str]) -> tuple[QuaternionGroup, ...]:
    """Every ``prefix.{x,y,z,w}`` quadruple among ``names`` (in order of first appearance)."""
    by_prefix: dict[str, dict[str, int]] = {}
    for index, name in enumerate(names):
        prefix, _, last = name.rpartition(".")
        if last in _XYZW:
            by_prefix.setdefault(prefix, {}).setdefault(last, index)
    groups = []
    for parts in by_prefix.values():
        if len(parts) == len(_XYZW):
            x, y, z, w = (parts[c] for c in _XYZW)
            groups.append((x, y, z, w))
    return tuple(groups)


def slerp(q0: FloatArray, q1: FloatArray, weight: FloatArray | float) -> FloatArray:
    """Spherical interpolation of unit quaternions (..., 4), along the shortest path; normalised output.

    ``q`` and ``-q`` are the same rotation: ``q1`` is flipped when that is shorter.  The inputs are
    normalised first (recorded quaternions drift off unit length).  Nearly equal inputs blend linearly;
    an all-zero input (an ``Imu`` without orientation estimate) blends linearly, unnormalised.
    """
    w = np.asarray(weight, dtype=np.float64)
    if w.ndim < q0.ndim:
        w = w[..., None]
    n0 = np.linalg.norm(q0, axis=-1, keepdims=True)
    n1 = np.linalg.norm(q1, axis=-1, keepdims=True)
    degenerate = (n0 == 0) | (n1 == 0)
    a = q0 / np.where(degenerate, 1.0, n0)
    b = q1 / np.where(degenerate, 1.0, n1)
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    parallel = dot > _NEARLY_PARALLEL
    safe = np.where(parallel, 1.0, sin_theta)
    s0 = np.where(parallel, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    s1 = np.where(parallel, w, np.sin(w * theta) / safe)
    out: FloatArray = s0 * a + s1 * b
    norm = np.linalg.norm(out, axis=-1, keepdims=True)
    unit: FloatArray = np.where(degenerate, (1.0 - w) * q0 + w * q1, out / np.where(norm == 0, 1.0, norm))
    return unit


def blend(
    lo: FloatArray, hi: FloatArray, weight: float, groups: Sequence[QuaternionGroup] = ()
) -> FloatArray:
    """``(1 - weight) * lo + weight * hi``, with every quaternion group slerped instead."""
    out: FloatArray = (1.0 - weight) * lo + weight * hi
    for group in groups:
        index = list(group)
        out[index] = slerp(np.asarray(lo[index], np.float64), np.asarray(hi[index], np.float64), weight)
    return out
