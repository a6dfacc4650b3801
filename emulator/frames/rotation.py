"""Unit quaternions ``[w, x, y, z]`` (scalar first) rotating body vectors into ENU.

scipy's :class:`~scipy.spatial.transform.Rotation` is scalar-last by default; every
conversion here passes ``scalar_first=True`` explicitly.

The batch model works *component-major*: quaternions as (4, N) and rotation matrices as
(3, 3, N), so that each entry is one contiguous array and the element-wise arithmetic
streams through memory instead of striding across (N, 3, 3) rows.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import PoseError

#: A quaternion with a smaller norm cannot be normalised meaningfully (BRIEF section 2).
MIN_QUATERNION_NORM = 1e-9


def unit_quaternion_components(q: ArrayLike, field: str = "orientation") -> NDArray[np.float64]:
    """Validate and normalise quaternions (..., 4), any float dtype; return (4, ...) float64.

    Raises :class:`PoseError` naming ``field`` for a non-finite component or a norm below
    1e-9. Components are divided by their largest magnitude before squaring, so neither
    1e+200 nor 1e-5 components lose the norm to overflow or underflow.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise PoseError(field, f"a quaternion has 4 components [w, x, y, z], got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise PoseError(field, "quaternion has a non-finite component")
    c = np.array(np.moveaxis(q, -1, 0), order="C")  # a private copy: normalised in place
    a = np.abs(c)
    scale = np.maximum(np.maximum(a[0], a[1]), np.maximum(a[2], a[3]))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        c /= scale
        norm_scaled = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[3] * c[3])
        norm = scale * norm_scaled  # may be inf for components near 1e308: still valid
    if np.any(~(norm >= MIN_QUATERNION_NORM)):
        bad = float(np.min(np.where(np.isnan(norm), 0.0, norm)))
        raise PoseError(field, f"quaternion norm {bad:.3g} is below {MIN_QUATERNION_NORM:g}")
    c /= norm_scaled
    return c


def normalize_quaternions(q: ArrayLike, field: str = "orientation") -> NDArray[np.float64]:
    """Unit float64 quaternions (..., 4); see :func:`unit_quaternion_components`."""
    return np.moveaxis(unit_quaternion_components(q, field), 0, -1)


def rotation_components(qc: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices (3, 3, ...) of unit quaternions given component-major (4, ...).

    Written out rather than through scipy because the batch model calls it on millions of
    poses and needs this layout (R maps body vectors into the world).
    """
    w, x, y, z = qc
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty((3, 3) + qc.shape[1:])
    m[0, 0] = 1.0 - 2.0 * (yy + zz)
    m[0, 1] = 2.0 * (xy - wz)
    m[0, 2] = 2.0 * (xz + wy)
    m[1, 0] = 2.0 * (xy + wz)
    m[1, 1] = 1.0 - 2.0 * (xx + zz)
    m[1, 2] = 2.0 * (yz - wx)
    m[2, 0] = 2.0 * (xz - wy)
    m[2, 1] = 2.0 * (yz + wx)
    m[2, 2] = 1.0 - 2.0 * (xx + yy)
    return m


def x_axis_components(qc: NDArray[np.float64]) -> NDArray[np.float64]:
    """R e_x, the body x axis in the world, (3, ...) from component-major quaternions."""
    w, x, y, z = qc
    return np.stack([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)])


def quaternion_matrices(q_unit: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) ``[w, x, y, z]``."""
    qc = np.moveaxis(np.asarray(q_unit, dtype=np.float64), -1, 0)
    return np.moveaxis(rotation_components(qc), (0, 1), (-2, -1))
