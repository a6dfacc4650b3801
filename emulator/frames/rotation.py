"""Unit quaternions ``[w, x, y, z]`` (scalar first) rotating body vectors into ENU.

Hamilton products, the exponential and logarithm maps (and so slerp) are written here in
numpy following scipy's formulas, not taken from scipy's ``Rotation``: importing
``scipy.spatial`` cost half of ``arva-emulate``'s start-up (docs/model.md section 1).

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
    c2 = c.reshape(4, -1)  # a view: rows stay arrays even for a single quaternion
    bad = normalize_components_inplace(c2, np.empty_like(c2))
    if bad is not None:
        raise PoseError(field, f"quaternion norm {bad:.3g} is below {MIN_QUATERNION_NORM:g}")
    return c


def normalize_components_inplace(c: NDArray[np.float64], work: NDArray[np.float64]) -> float | None:
    """Normalise finite component-major quaternions ``c`` (4, n) in place.

    ``work`` is (4, n) scratch. Returns None, or the smallest norm when one is below
    MIN_QUATERNION_NORM (``c`` is then left partly scaled). The arithmetic of
    :func:`unit_quaternion_components`, which calls this; the batch model calls it per
    block of poses with reused buffers.
    """
    a = np.abs(c, out=work)  # then reused (in place, no further temporaries) as scratch rows
    scale = np.maximum(a[0], a[1], out=a[0])
    np.maximum(scale, np.maximum(a[2], a[3], out=a[2]), out=scale)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        c /= scale
        # norm_scaled = sqrt(((c0^2 + c1^2) + c2^2) + c3^2)
        norm_scaled, square = a[1], a[2]
        np.multiply(c[0], c[0], out=norm_scaled)
        for k in (1, 2, 3):
            np.multiply(c[k], c[k], out=square)
            norm_scaled += square
        np.sqrt(norm_scaled, out=norm_scaled)
        norm = np.multiply(scale, norm_scaled, out=a[3])  # may be inf near 1e308: still valid
    if not norm.min(initial=np.inf) >= MIN_QUATERNION_NORM:  # also a nan norm
        return float(np.min(np.where(np.isnan(norm), 0.0, norm)))
    c /= norm_scaled
    return None


def normalize_quaternions(q: ArrayLike, field: str = "orientation") -> NDArray[np.float64]:
    """Unit float64 quaternions (..., 4); see :func:`unit_quaternion_components`."""
    return np.moveaxis(unit_quaternion_components(q, field), 0, -1)


def rotation_components(qc: NDArray[np.float64], out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Rotation matrices (3, 3, ...) of unit quaternions given component-major (4, ...).

    Written out rather than through scipy because the batch model calls it on millions of
    poses and needs this layout (R maps body vectors into the world). ``out`` (3, 3, ...)
    receives the result; every entry is computed in place there (no temporaries beyond
    the nine products), e.g. m[0, 0] = 1 - 2 (yy + zz), m[0, 1] = 2 (xy - wz).
    """
    shape = qc.shape[1:]
    w, x, y, z = np.asarray(qc).reshape(4, -1)  # rows stay arrays for a single quaternion
    products = np.empty((9,) + w.shape)
    xx, yy, zz, xy, xz, yz, wx, wy, wz = products
    for a, b, o in ((x, x, xx), (y, y, yy), (z, z, zz), (x, y, xy), (x, z, xz), (y, z, yz),
                    (w, x, wx), (w, y, wy), (w, z, wz)):
        np.multiply(a, b, out=o)
    m = np.empty((3, 3) + shape) if out is None else out
    flat = m.reshape(3, 3, -1)
    if m.size and not np.shares_memory(flat, m):  # out= must take the entries in place
        raise ValueError("rotation_components: out must be reshapeable to (3, 3, -1) without a copy")
    for i, j, a, b, op, diagonal in _ROTATION_ENTRIES:
        e = flat[i, j]
        op(products[a], products[b], out=e)
        e *= 2.0
        if diagonal:
            np.subtract(1.0, e, out=e)
    return m


# (row, column, product, product, +/-, diagonal) of R from the products
# xx yy zz xy xz yz wx wy wz (indices 0..8): diagonal entries are 1 - 2 (a + b).
_ROTATION_ENTRIES = (
    (0, 0, 1, 2, np.add, True),
    (0, 1, 3, 8, np.subtract, False),
    (0, 2, 4, 7, np.add, False),
    (1, 0, 3, 8, np.add, False),
    (1, 1, 0, 2, np.add, True),
    (1, 2, 5, 6, np.subtract, False),
    (2, 0, 4, 7, np.subtract, False),
    (2, 1, 5, 6, np.add, False),
    (2, 2, 0, 1, np.add, True),
)


def x_axis_components(qc: NDArray[np.float64]) -> NDArray[np.float64]:
    """R e_x, the body x axis in the world, (3, ...) from component-major quaternions."""
    w, x, y, z = qc
    return np.stack([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)])


def quaternion_matrices(q_unit: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) ``[w, x, y, z]``."""
    qc = np.moveaxis(np.asarray(q_unit, dtype=np.float64), -1, 0)
    return np.moveaxis(rotation_components(qc), (0, 1), (-2, -1))


def rotation_unnormalized_components(
    qc: NDArray[np.float64], out: NDArray[np.float64], work: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Rotation matrices (3, 3, n) of q / |q| for finite component-major quaternions ``qc`` (4, n).

    Without normalising q first: with k = 2 / |q|^2 the entries are 1 - k (yy + zz),
    k (xy - wz), ... (the products scaled once by k). ``work`` is (12, n) scratch; ``out``
    (3, c, n), c <= 3, receives the first c columns and may be a transposed view. Returns
    |q|^2 (n,), a row of ``work``: the caller checks its range, since |q|^2 may under- or
    overflow for components beyond about 1e+-150 (then use
    :func:`unit_quaternion_components`). The same matrices as :func:`rotation_components`
    of the normalised quaternion to a few ulps (the batch model's per-pose work).
    """
    sq, n2, k, kq, dg = work[0:4], work[4], work[5], work[6:9], work[9:12]
    np.multiply(qc, qc, out=sq)
    np.add(sq[0:2], sq[2:4], out=sq[0:2])
    np.add(sq[0], sq[1], out=n2)  # |q|^2
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        np.divide(2.0, n2, out=k)
        np.multiply(qc[1:], k, out=kq)  # k x, k y, k z
        np.multiply(kq, qc[1:], out=dg)  # k xx, k yy, k zz
        xx, yy, zz = dg
        np.multiply(kq[0:2], qc[2:4], out=sq[0:2])  # k xy, k yz (the squares are spent)
        np.multiply(kq[0], qc[3], out=sq[2])  # k xz
        xy, yz, xz = sq[0], sq[1], sq[2]
        kq *= qc[0]  # k wx, k wy, k wz, in place: the last use of k x, k y, k z
        wx, wy, wz = kq
        m = out  # column by column: out may hold only the first columns
        np.add(yy, zz, out=m[0, 0])
        np.subtract(1.0, m[0, 0], out=m[0, 0])
        np.add(xy, wz, out=m[1, 0])
        np.subtract(xz, wy, out=m[2, 0])
        if out.shape[1] > 1:
            np.subtract(xy, wz, out=m[0, 1])
            np.add(xx, zz, out=m[1, 1])
            np.subtract(1.0, m[1, 1], out=m[1, 1])
            np.add(yz, wx, out=m[2, 1])
        if out.shape[1] > 2:
            np.add(xz, wy, out=m[0, 2])
            np.subtract(yz, wx, out=m[1, 2])
            np.add(xx, yy, out=m[2, 2])
            np.subtract(1.0, m[2, 2], out=m[2, 2])
    return n2


#: Below this angle (rad) the exponential and logarithm maps use their Taylor series
#: (as scipy's Rotation does): sin(a/2)/a and a/sin(a/2) lose digits there.
_SMALL_ANGLE = 1e-3


def quaternion_products(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton products ``p q`` of quaternions (..., 4) ``[w, x, y, z]``: the rotation
    q followed by p (for body-side composition, R_p R_q)."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=np.float64), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def rotvec_quaternions(v: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions (..., 4) of rotation vectors (..., 3) in radians (axis times
    angle): the exponential map."""
    v = np.asarray(v, dtype=np.float64)
    angle = np.sqrt(np.sum(v * v, axis=-1, keepdims=True))
    small = angle <= _SMALL_ANGLE
    a2 = angle * angle
    scale = np.where(small, 0.5 - a2 / 48.0 + a2 * a2 / 3840.0, np.sin(0.5 * angle) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(0.5 * angle), v * scale], axis=-1)


def quaternion_rotvecs(q_unit: ArrayLike) -> NDArray[np.float64]:
    """Rotation vectors (..., 3), angle in [0, pi], of unit quaternions (..., 4): the
    logarithm map (q and -q give the same vector).

    A half turn (w = 0) has two vectors, +pi and -pi about the axis: as scipy does, the
    sign of q is taken so that its first non-zero component is positive (so a waypoint
    path turning by exactly 180 degrees turns the same way as it did through scipy)."""
    q = np.asarray(q_unit, dtype=np.float64)
    w, x, y, z = np.moveaxis(q, -1, 0)
    flip = (w < 0.0) | ((w == 0.0) & ((x < 0.0) | ((x == 0.0) & ((y < 0.0) | ((y == 0.0) & (z < 0.0))))))
    q = np.where(flip[..., None], -q, q)
    v = q[..., 1:]
    angle = 2.0 * np.arctan2(np.sqrt(np.sum(v * v, axis=-1, keepdims=True)), q[..., :1])
    small = angle <= _SMALL_ANGLE
    a2 = angle * angle
    scale = np.where(small, 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0, angle / np.where(small, 1.0, np.sin(0.5 * angle)))
    return v * scale


def quaternion_conjugates(q: ArrayLike) -> NDArray[np.float64]:
    """Conjugates (..., 4): the inverse rotations of unit quaternions."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])
