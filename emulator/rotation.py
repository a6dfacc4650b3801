"""Unit quaternions ``[w, x, y, z]`` (scalar first) rotating body vectors into ENU.

scipy's :class:`~scipy.spatial.transform.Rotation` is scalar-last by default; every
conversion here passes ``scalar_first=True`` explicitly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import PoseError

#: A quaternion with a smaller norm cannot be normalised meaningfully (BRIEF section 2).
MIN_QUATERNION_NORM = 1e-9


def normalize_quaternions(q: ArrayLike, field: str = "orientation") -> NDArray[np.float64]:
    """Return ``q`` (shape (..., 4), any float dtype) as unit float64 quaternions.

    Raises :class:`PoseError` naming ``field`` for a non-finite component or a norm below
    1e-9. Components are divided by their largest magnitude before squaring, so neither
    1e+200 nor 1e-5 components lose the norm to overflow or underflow.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise PoseError(field, f"a quaternion has 4 components [w, x, y, z], got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise PoseError(field, "quaternion has a non-finite component")
    scale = np.max(np.abs(q), axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        unit = q / scale
        norm_scaled = np.sqrt(np.sum(unit * unit, axis=-1, keepdims=True))
        norm = scale * norm_scaled  # may be inf for components near 1e308: still valid
    if np.any(~(norm >= MIN_QUATERNION_NORM)):
        bad = float(np.min(np.where(np.isnan(norm), 0.0, norm)))
        raise PoseError(field, f"quaternion norm {bad:.3g} is below {MIN_QUATERNION_NORM:g}")
    return unit / norm_scaled


def quaternion_matrices(q_unit: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) ``[w, x, y, z]``.

    Written out rather than through scipy because the batch model calls it on millions of
    poses and this is the one formula it needs (R maps body vectors into the world).
    """
    w, x, y, z = np.moveaxis(q_unit, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty(q_unit.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1.0 - 2.0 * (yy + zz)
    m[..., 0, 1] = 2.0 * (xy - wz)
    m[..., 0, 2] = 2.0 * (xz + wy)
    m[..., 1, 0] = 2.0 * (xy + wz)
    m[..., 1, 1] = 1.0 - 2.0 * (xx + zz)
    m[..., 1, 2] = 2.0 * (yz - wx)
    m[..., 2, 0] = 2.0 * (xz - wy)
    m[..., 2, 1] = 2.0 * (yz + wx)
    m[..., 2, 2] = 1.0 - 2.0 * (xx + yy)
    return m
