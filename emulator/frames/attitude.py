"""Heading / roll / pitch as attitude sensors print them  <->  our quaternions.

Our orientation (BRIEF section 2): unit quaternion ``[w, x, y, z]`` rotating vectors of a
body frame with x forward, y left, z up (FLU) into the world frame ENU (x east, y north,
z up).

Attitude units that emit ``$PASHR`` (OxTS, Applanix POS MV, Hemisphere, ...) and most
marine/aviation AHRS use the aerospace Tait-Bryan convention instead:

* **heading** psi, degrees true, clockwise from true north seen from above, [0, 360);
* **pitch** theta, degrees, positive **nose (bow) up**, [-90, 90];
* **roll** phi, degrees, positive **right (starboard) side down** -- "port side up" in the
  vendor manuals -- [-180, 180];
* applied as the **intrinsic Z-Y'-X'' (yaw, then pitch, then roll)** sequence to a body
  frame x forward, y right, z down (FRD) starting aligned with **NED**::

      R_ned<-frd = Rz(psi) Ry(theta) Rx(phi)

  (right-handed rotations about the NED down axis, then the new y, then the new x).

In our frames that is R_enu<-flu = Rz(90 deg - psi) Ry(-theta) Rx(phi) (intrinsic again),
which :func:`hpr_to_quaternion` builds: heading 90 points body x east, pitch +30 gives
body x an up component of +0.5, roll +30 gives body y (left) one of +0.5. The
derivation, the inverse and gimbal lock (pitch +-90 deg: roll 0, the whole vertical
rotation in the heading): docs/emulator.md "Attitude convention".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import PoseError

from emulator.frames.geodesy import finite_arrays
from emulator.frames.rotation import normalize_quaternions, quaternion_matrices

_GIMBAL_LOCK_COS = 1e-10

HPR = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def wrap_heading(heading_deg: ArrayLike) -> NDArray[np.float64]:
    """Headings wrapped into [0, 360) degrees (``-1e-17 % 360`` is 360.0 in floats: fixed)."""
    h = np.mod(np.asarray(heading_deg, dtype=np.float64), 360.0)
    return np.where(h >= 360.0, 0.0, h)


def hpr_to_quaternion(heading: ArrayLike, roll: ArrayLike, pitch: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions (..., 4) ``[w, x, y, z]`` (w >= 0) of heading/roll/pitch in degrees.

    Any finite angles are accepted (a pitch beyond +-90 is still a rotation); non-finite
    ones raise :class:`~firmware_proto.errors.PoseError` naming the field.

    Computed as the product of the three half-angle quaternions
    q = qz(90 deg - heading) * qy(-pitch) * qx(roll), written out: the bench calls this
    once per $PASHR sentence, where scipy's ``Rotation.from_euler`` (which the tests
    check this against) costs ten times more for one rotation.
    """
    h, r, p = finite_arrays(PoseError, heading=heading, roll=roll, pitch=pitch)
    half = np.radians(0.5)
    a, b, c = (90.0 - h) * half, -p * half, r * half
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    w = ca * cb * cc + sa * sb * sc
    x = ca * cb * sc - sa * sb * cc
    y = ca * sb * cc + sa * cb * sc
    z = sa * cb * cc - ca * sb * sc
    q = np.stack(np.broadcast_arrays(w, x, y, z), axis=-1)
    return np.where(q[..., :1] < 0.0, -q, q)


def quaternion_to_hpr(q: ArrayLike, field: str = "orientation") -> HPR:
    """(heading [0, 360), roll [-180, 180], pitch [-90, 90]) in degrees of quaternions (..., 4).

    Quaternions are normalised first; a non-finite component or a norm < 1e-9 raises
    :class:`~firmware_proto.errors.PoseError` naming ``field``.
    """
    m = quaternion_matrices(normalize_quaternions(q, field))
    r00, r10, r20 = m[..., 0, 0], m[..., 1, 0], m[..., 2, 0]
    r01, r11, r21 = m[..., 0, 1], m[..., 1, 1], m[..., 2, 1]
    cos_pitch = np.hypot(r00, r10)
    locked = cos_pitch < _GIMBAL_LOCK_COS
    theta = np.arctan2(r20, cos_pitch)  # pitch
    # alpha = 90 deg - heading: the ENU yaw of body x, counter-clockwise from east.
    alpha = np.where(locked, np.arctan2(-r01, r11), np.arctan2(r10, r00))
    # Roll from the residual Rx(phi) = Ry(-theta)^T Rz(alpha)^T R (docs/emulator.md,
    # "Attitude convention": exact near gimbal lock).
    sa, ca = np.sin(alpha), np.cos(alpha)
    sin_roll = -np.sin(theta) * (ca * r01 + sa * r11) + np.cos(theta) * r21
    cos_roll = ca * r11 - sa * r01
    roll = np.where(locked, 0.0, np.degrees(np.arctan2(sin_roll, cos_roll)))
    heading = wrap_heading(90.0 - np.degrees(alpha))
    return np.asarray(heading), np.asarray(roll), np.asarray(np.degrees(theta))
