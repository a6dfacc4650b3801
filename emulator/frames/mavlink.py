"""MAVLink frames (common message set) <-> ours (BRIEF 2: ENU world, FLU body).

* Positions and velocities (``LOCAL_POSITION_NED``): x north, y east, z down, metres.
  ENU is (east, north, up) = (y, x, -z): p_enu = T p_ned with
  T = [[0, 1, 0], [1, 0, 0], [0, 0, -1]].
* ``ATTITUDE_QUATERNION``: q1..q4 = [w, x, y, z] rotating the FRD body frame (x forward,
  y right, z down) into NED. Our body frame is FLU: v_frd = F v_flu with
  F = diag(1, -1, -1). So R_enu_flu = T R_ned_frd F; T is the rotation by pi about
  (1, 1, 0)/sqrt(2), q_T = [0, 1/sqrt2, 1/sqrt2, 0]; F the rotation by pi about x,
  q_F = [0, 1, 0, 0]; q_enu_flu = q_T * q_ned_frd * q_F (Hamilton products).
* ``ATTITUDE``: roll, pitch, yaw in radians, aerospace Z-Y-X, yaw clockwise from north:
  the ``$PASHR`` convention (:mod:`emulator.frames.attitude`) in radians.

A NED yaw psi (clockwise from north) is the ENU yaw 90 deg - psi (counter-clockwise from
east). Used by the emulator's MAVLink ride-along and by the bench's MAVLink reader.
"""

from __future__ import annotations

import math

import numpy as np

from emulator.frames.attitude import hpr_to_quaternion
from emulator.frames.rotation import quaternion_products

_SQRT_HALF = math.sqrt(0.5)
_Q_T = (0.0, _SQRT_HALF, _SQRT_HALF, 0.0)  # NED <-> ENU (its own inverse)
_Q_F = (0.0, 1.0, 0.0, 0.0)  # FLU <-> FRD (its own inverse)


def ned_to_enu(v) -> tuple[float, float, float]:
    """(north, east, down) -> (east, north, up)."""
    return (float(v[1]), float(v[0]), -float(v[2]))


def frd_ned_to_flu_enu(q_ned_frd) -> tuple[float, float, float, float]:
    """ATTITUDE_QUATERNION's [q1, q2, q3, q4] (FRD -> NED) as our [w, x, y, z] (FLU -> ENU),
    normalised, with w >= 0. ValueError for a degenerate quaternion."""
    with np.errstate(invalid="ignore", over="ignore"):  # a non-finite input is refused below
        q_in = [float(c) for c in q_ned_frd]
        q = tuple(float(c) for c in quaternion_products(quaternion_products(_Q_T, q_in), _Q_F))
    n = math.sqrt(sum(c * c for c in q))
    if not n > 1e-9 or not math.isfinite(n):
        raise ValueError(f"ATTITUDE_QUATERNION: degenerate quaternion {list(q_ned_frd)}")
    s = 1.0 / n if q[0] >= 0 else -1.0 / n
    return tuple(c * s for c in q)


def attitude_euler_to_hpr(roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """ATTITUDE's roll, pitch, yaw (radians) as ($PASHR) heading in [0, 360), roll, pitch
    (degrees). ValueError for a non-finite angle."""
    r, p, h = (math.degrees(a) for a in (roll, pitch, yaw))
    if not all(math.isfinite(a) for a in (r, p, h)):
        raise ValueError("ATTITUDE: non-finite angle")
    return h % 360.0, r, p


def attitude_euler_to_flu_enu(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ATTITUDE's roll, pitch, yaw (radians) as our [w, x, y, z] (FLU -> ENU), w >= 0."""
    heading, r, p = attitude_euler_to_hpr(roll, pitch, yaw)
    return tuple(float(c) for c in hpr_to_quaternion(heading, r, p))
