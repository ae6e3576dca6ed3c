"""Ground truth of a synthetic episode: analytic joint trajectories and every stamp written."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bagport.synth.spec import EpisodeSpec

__all__ = ["GroundTruth"]

NS = 1_000_000_000
Float = npt.NDArray[np.float64]
Int64 = npt.NDArray[np.int64]


def _periodic_ns(start_ns: int, duration_s: float, rate_hz: float, offset_ns: int = 0) -> Int64:
    count = int(np.floor(duration_s * rate_hz)) + 1
    k = np.arange(count, dtype=np.int64)
    return start_ns + offset_ns + np.round(k * (NS / rate_hz)).astype(np.int64)


class GroundTruth:
    """Pure functions of time: what the robot really did, and when each message was captured."""

    def __init__(self, spec: EpisodeSpec) -> None:
        self.spec = spec
        rng = np.random.default_rng(spec.seed)
        n = len(spec.joint_names)
        self._freq_hz = rng.uniform(0.1, 0.5, n)
        self._amp = rng.uniform(0.2, 1.0, n)
        self._phase = rng.uniform(0, 2 * np.pi, n)
        self._offset = rng.uniform(-0.5, 0.5, n)
        self._joint_ns = _periodic_ns(spec.start_ns, spec.duration_s, spec.joint_rate_hz)
        self._action_ns = _periodic_ns(
            spec.start_ns, spec.duration_s, spec.action_rate_hz, offset_ns=1_000_000
        )
        self._camera_ns: dict[str, Int64] = {}
        for index, cam in enumerate(spec.cameras):
            base = _periodic_ns(
                spec.start_ns, spec.duration_s, cam.rate_hz, offset_ns=3_000_000 * (index + 1)
            )
            jitter = rng.integers(-cam.jitter_ns, cam.jitter_ns + 1, base.size) if cam.jitter_ns else 0
            self._camera_ns[cam.name] = base + jitter

    def _t_s(self, t_ns: Int64 | int) -> Float:
        return (np.asarray(t_ns, dtype=np.int64) - self.spec.start_ns).astype(np.float64)[..., None] / NS

    def joint_position(self, t_ns: Int64 | int) -> Float:
        """True joint positions (rad) at absolute time ``t_ns``; shape (..., joints)."""
        t = self._t_s(t_ns)
        position: Float = self._amp * np.sin(2 * np.pi * self._freq_hz * t + self._phase) + self._offset
        return position

    def joint_velocity(self, t_ns: Int64 | int) -> Float:
        t = self._t_s(t_ns)
        velocity: Float = (
            self._amp * 2 * np.pi * self._freq_hz * np.cos(2 * np.pi * self._freq_hz * t + self._phase)
        )
        return velocity

    def joint_effort(self, t_ns: Int64 | int) -> Float:
        return 0.1 * self.joint_position(t_ns)

    def action_position(self, t_ns: Int64 | int) -> Float:
        lead_ns = round(self.spec.action_lead_s * NS)
        return self.joint_position(np.asarray(t_ns, dtype=np.int64) + lead_ns)

    def joint_stamps_ns(self) -> Int64:
        return self._joint_ns.copy()

    def action_stamps_ns(self) -> Int64:
        return self._action_ns.copy()

    def camera_stamps_ns(self, name: str) -> Int64:
        return self._camera_ns[name].copy()

    @property
    def task_stamp_ns(self) -> int:
        return self.spec.start_ns
