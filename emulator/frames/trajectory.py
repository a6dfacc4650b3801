"""Poses over time: a static pose, or waypoints interpolated linearly in position and by
slerp in orientation, held before the first and after the last waypoint (BRIEF 5)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from emulator.frames.rotation import (
    normalize_quaternions, quaternion_conjugates, quaternion_products, quaternion_rotvecs, rotvec_quaternions,
)

IDENTITY = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Trajectory:
    """Waypoints ``times`` (K,) in seconds, strictly increasing; ``positions`` (K, 3) in
    ENU metres; ``orientations`` (K, 4) unit quaternions [w, x, y, z]. K = 1 is static."""

    times: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]

    @classmethod
    def static(cls, position: ArrayLike, orientation: ArrayLike = IDENTITY) -> "Trajectory":
        pos, quat = (np.asarray(v, dtype=np.float64) for v in (position, orientation))
        return cls(np.zeros(1), pos.reshape(1, 3), quat.reshape(1, 4))

    @property
    def is_static(self) -> bool:
        return len(self.times) == 1

    def at(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions (N, 3) and orientations (N, 4) at times ``t`` (N,) in seconds."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        if self.is_static:
            return np.broadcast_to(self.positions[0], (t.size, 3)), np.broadcast_to(self.orientations[0], (t.size, 4))
        # np.interp holds the end values outside [t0, tK], as a held pose should.
        pos = np.stack([np.interp(t, self.times, self.positions[:, i]) for i in range(3)], axis=1)
        clipped = np.clip(t, self.times[0], self.times[-1])
        # Slerp: the waypoint before t turned by the fraction of its segment's rotation.
        starts, rotvecs = self._segments
        i = np.searchsorted(self.times, clipped, side="left") - 1
        i[i < 0] = 0  # t at the first waypoint: the start of the first segment
        frac = (clipped - self.times[i]) / (self.times[i + 1] - self.times[i])
        quat = quaternion_products(starts[i], rotvec_quaternions(rotvecs[i] * frac[:, None]))
        return pos, quat

    def velocity(self, t: ArrayLike) -> NDArray[np.float64]:
        """Velocities (N, 3) in m/s at times ``t`` (N,): the segment being travelled from
        ``t`` on (at a waypoint, the one that starts there), zero before the first and
        from the last waypoint on (the pose is held)."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        out = np.zeros((t.size, 3))
        if self.is_static:
            return out
        i = np.searchsorted(self.times, t, side="right") - 1
        moving = (i >= 0) & (i < len(self.times) - 1)
        j = i[moving]
        dt = self.times[j + 1] - self.times[j]
        out[moving] = (self.positions[j + 1] - self.positions[j]) / dt[:, None]
        return out

    @cached_property
    def _segments(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(unit waypoint quaternions (K, 4), each segment's rotation vector (K-1, 3) in its
        start's body frame), built once."""
        unit = normalize_quaternions(self.orientations, "trajectory.orientation")
        rel = quaternion_products(quaternion_conjugates(unit[:-1]), unit[1:])
        return unit, quaternion_rotvecs(rel)
