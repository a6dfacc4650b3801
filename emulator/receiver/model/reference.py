"""The reference formula of BRIEF section 3: field, zones and (d, delta) for blocks of pairs.

Units and frames as in :mod:`.types` (metres in the world ENU frame, ``d`` in centimetres,
``delta`` in degrees, the field in scene units); the transmitter dipole points along its +x.

Written in the scale-free form of docs/model.md section 2 (h = s / (4 pi r^3) u with
1 <= |u| <= 2, d3 = r cbrt(kappa_eq / s) / cbrt(|u|)), so no intermediate over- or
underflows for any finite r > 0; with noise the larger of the signal and noise terms is
factored out (section 4); the 2-antenna class uses dxy in every zone (section 8).

This is the general path: every receiver class, noise, the field, moving transmitters.
:mod:`emulator.receiver.model.fast` computes the common case faster and hands back every
pair it cannot decide to :func:`measure_pairs` here.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from emulator.frames.rotation import normalize_components_inplace, rotation_components, unit_quaternion_components
from emulator.receiver.model.types import FIELD_SATURATION, HUGE, MAX_DELTA_DEG, ZONE_INNER, Batch, max_abs

# Squares of components between these bounds neither underflow nor overflow, so the
# plain sqrt of the sum of squares is exact to an ulp; outside them we fall back to
# hypot (slow but safe). This keeps the common case 4x faster than hypot everywhere.
_SQ_LO, _SQ_HI = 1e-290, 1e290
#: Without noise |g| <= 2 up to a few ulps: d3 <= r_inner needs dist_scale <= r_inner * this.
CBRT2_MARGIN = math.cbrt(2.0) * (1.0 + 1e-9)
#: The one x in [0, 2^52) with floor(x + 0.5) != round-half-away(x) (x + 0.5 rounds up to 1).
_BELOW_HALF = 0.49999999999999994
NO_INDEX = np.empty(0, dtype=np.intp)


def round_half_away(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Round to the nearest integer, halves away from zero (not banker's rounding).

    ``x - trunc(x)`` is exact in binary floating point, so 0.49999999999999994 stays 0
    (``floor(x + 0.5)`` would give 1).
    """
    t = np.trunc(x)
    return t + np.where(np.abs(x - t) >= 0.5, np.sign(x), 0.0)


def norm3(x, y, z):
    """Euclidean norm of (x, y, z), element-wise, without under- or overflow."""
    with np.errstate(over="ignore", under="ignore"):
        s = x * x + y * y + z * z
    r = np.sqrt(s)
    bad = ~((s > _SQ_LO) & (s < _SQ_HI))
    if bad.any():
        r[bad] = np.hypot(np.hypot(x[bad], y[bad]), z[bad])
    return r


# -- Driving blocks: poses of a call, or pairs a fast path left undecided ---------------
def measure_poses(batch: Batch, first: int, last: int) -> None:
    """Poses first..last-1 of ``batch`` on the general path, block by block, with buffers
    of their own (so threads may run disjoint ranges).

    Layout of a block: 2-D, its inner (contiguous) axis the longer of poses and
    transmitters, so every ufunc runs long contiguous loops with per-pose or
    per-transmitter values broadcast as scalars along it.
    """
    m, rows = batch.m, batch.rows
    tx_major = batch.d.shape[0] >= m
    rx_p, rx_q, tx_p, tx_m = batch.rx_p, batch.rx_q, batch.tx_p, batch.tx_m
    size = min(last - first, rows)
    scratch = Scratch(size * m)
    rot = np.empty((3, 3, size))
    q_rows, q_work = np.empty((4, size)), np.empty((4, size))
    # Per-pose rows, per-transmitter rows and (rows, M) slices as the layout wants them.
    pose = lambda a: a[None, :] if tx_major else a[:, None]  # noqa: E731
    txs = lambda a: a[:, None] if tx_major else a[None, :]  # noqa: E731
    pair = lambda a: a.T if tx_major else a  # noqa: E731
    with np.errstate(all="ignore"):
        for lo in range(first, last, rows):
            hi = min(last, lo + rows)
            sl = slice(lo, hi)
            if batch.moving_tx:
                tx = tuple(pair(tx_p[sl, :, k]) for k in range(3))
                tm = tuple(pair(tx_m[k, sl]) for k in range(3))
            else:
                tx = tuple(txs(tx_p[:, k]) for k in range(3))
                tm = tuple(txs(tx_m[k]) for k in range(3))
            f = 1.0
            if batch.any_big:  # a block holding coordinates beyond HUGE is scaled by 1/4
                big = max(np.max(np.abs(rx_p[sl]), initial=0.0),
                          np.max(np.abs(tx_p[sl] if batch.moving_tx else tx_p), initial=0.0)) > HUGE
                f = 0.25 if big else 1.0
            qc = q_rows[:, : hi - lo]
            np.copyto(qc, rx_q[sl].T)
            if normalize_components_inplace(qc, q_work[:, : hi - lo]) is not None:
                # report it as for the whole array (e.g. its smallest norm)
                unit_quaternion_components(rx_q, "receiver.orientation")
            rx_r = rotation_components(qc, out=rot[:, :, : hi - lo])
            measure_block(
                tuple(pose(rx_c) for rx_c in np.ascontiguousarray(rx_p[sl].T)),
                tuple(tuple(pose(rx_r[i, j]) for j in range(3)) for i in range(3)),
                tx,
                tm,
                f,
                batch.params,
                None if batch.noise is None else tuple(pair(batch.noise[sl, :, k]) for k in range(3)),
                pair(batch.d[sl]),
                pair(batch.delta[sl]),
                pair(batch.zone[sl]),
                None if batch.field is None else tuple(pair(batch.field[sl, :, k]) for k in range(3)),
                scratch.view((m, hi - lo) if tx_major else (hi - lo, m)),
            )


def measure_pairs(batch: Batch, general: list[NDArray[np.intp]]) -> None:
    """The pairs a fast path left undecided (lists of flat indices into the (N, M)
    outputs; static transmitters) on the general path, in blocks of ``batch.chunk``."""
    flat = np.concatenate(general) if general else NO_INDEX
    with np.errstate(all="ignore"):
        for lo in range(0, flat.size, batch.chunk):  # in blocks: all pairs may be here
            part = flat[lo:lo + batch.chunk]
            ip, it = np.divmod(part, batch.m)
            out = _pairs(batch, ip, it)
            for arr, val in zip((batch.d, batch.delta, batch.zone), out):
                arr.reshape(-1)[part] = val


def _pairs(batch: Batch, ip, it):
    """(d, delta, zone) of the pairs (rx ip[k], tx it[k]) on the general path (1-D)."""
    rx_p, rx_q, tx_p, tx_m = batch.rx_p, batch.rx_q, batch.tx_p, batch.tx_m
    k = ip.size
    qc = np.ascontiguousarray(rx_q[ip].T)
    if normalize_components_inplace(qc, np.empty_like(qc)) is not None:
        unit_quaternion_components(rx_q, "receiver.orientation")  # as for the whole array
    rr = rotation_components(qc)
    row = lambda a: a.reshape(1, k)  # noqa: E731
    rx = tuple(row(rx_p[ip, c]) for c in range(3))
    tx = tuple(row(tx_p[it, c]) for c in range(3))
    big = max(max_abs(np.stack(rx)), max_abs(np.stack(tx))) > HUGE
    out = (np.empty((1, k), np.int64), np.empty((1, k), np.int64), np.empty((1, k), np.int8))
    with np.errstate(all="ignore"):
        measure_block(rx, tuple(tuple(row(rr[i, j]) for j in range(3)) for i in range(3)), tx,
                      tuple(row(tx_m[c, it]) for c in range(3)), 0.25 if big else 1.0, batch.params, None,
                      *out, None, Scratch(k).view((1, k)))
    return tuple(o.reshape(-1) for o in out)


class Scratch:
    """Preallocated float64 and bool buffers for one block (reused by every block)."""

    FLOATS, BOOLS = 12, 3

    def __init__(self, size: int) -> None:
        self.f = np.empty((self.FLOATS, size))
        self.b = np.empty((self.BOOLS, size), dtype=bool)

    def view(self, shape: tuple[int, int]) -> tuple[list, list]:
        size = shape[0] * shape[1]
        return ([a[:size].reshape(shape) for a in self.f], [a[:size].reshape(shape) for a in self.b])


# -- One block of pairs ----------------------------------------------------------------
def measure_block(rx, rr, tx, tm, f, params, noise, d_out, delta_out, zone_out, field_out, scratch):
    """One block of pairs. Every array argument broadcasts to the block's 2-D shape.

    ``rx`` receiver positions (3 rows), ``rr`` its rotation (3 x 3 rows), ``tx``
    transmitter positions and ``tm`` dipole axes m = R_t e_x (3 rows each), world frame,
    metres: u_w = 3 (m.n) n - m is eq. 1 rotated by R_t, in 3x fewer operations
    (docs/model.md section 2, steps 1-2).

    Written with ``out=`` into preallocated buffers and in-place ufuncs (no temporaries
    on the common path) and the same floating-point operations in the same order as the
    plain formulas, so the results are bit for bit those of the straightforward version.
    A block whose coordinates exceed ~1e307 arrives with f = 1/4 (exact for normal floats):
    differences are scaled down and distances back up (to inf: outer).
    """
    (dx, dy, dz, r, t, g0, g1, g2, a, b, k_mid, o_out), (m1, m2, m3) = scratch
    shape = dx.shape
    at_tx = _unit_separation(rx, tx, f, (dx, dy, dz), r, t, a)
    r_safe = r if f == 1.0 else r / f  # true distance; inf only for pairs ~1e308 m apart
    uw = _dipole_direction(tm, (dx, dy, dz), t, a)
    # Receiver frame: g = R_r^T u_w (h = s / (4 pi r^3) g). g_z is needed densely only with
    # noise or for the field; otherwise only for the few pairs that may be inner (below).
    three = params.antennas == 3
    dense_gz = noise is not None or field_out is not None
    for i, g in enumerate((g0, g1, g2) if dense_gz else (g0, g1)):
        np.multiply(rr[0][i], dx, out=g)
        np.multiply(rr[1][i], dy, out=t)
        g += t
        np.multiply(rr[2][i], dz, out=t)
        g += t

    field_scale = None
    if noise is None:
        if field_out is not None:
            field_scale = (params.moment / (4.0 * math.pi)) / r_safe**3
        dist_scale = np.multiply(r_safe, params.distance_scale, out=r if f == 1.0 else None)
    else:
        g0, g1, g2, dist_scale, field_scale = _add_noise(
            g0, g1, g2, r_safe, rr, noise, params, field_out is not None
        )

    at_idx = np.flatnonzero(at_tx) if at_tx is not None else NO_INDEX
    if three:
        inner_idx, inner_d3 = _inner_by_d3(params, noise, dist_scale, (g0, g1, g2), dense_gz, uw, rr, m1)
    dxy = _horizontal_distance(g0, g1, dist_scale, dx, t, dz, a)
    if not three:  # 2 antennas: the horizontal field in every zone
        inner_idx = np.flatnonzero(np.less_equal(dxy, params.r_inner, out=m1))
    inner_all = np.concatenate((inner_idx, at_idx)) if at_idx.size else inner_idx
    _zones(dxy, params, inner_all, zone_out, k_mid, o_out, m2)

    dist = dxy
    if three and inner_idx.size:
        dist.reshape(-1)[inner_idx] = inner_d3
    if at_idx.size:
        dist.reshape(-1)[at_idx] = 0.0
    _write_distance(dist, params, k_mid, o_out, t, d_out)
    _write_angle(g0, g1, inner_all, k_mid, o_out, a, t, m3, delta_out)
    if field_out is not None:
        _write_field((g0, g1, g2), field_scale, at_tx, shape, params, field_out)


def _unit_separation(rx, tx, f, n, r, t, s):
    """n <- (p_r - p_t) / r and r <- |p_r - p_t| (both scaled by f), in place.

    Returns a bool array of the pairs at r = 0 (whose r is set to 1), or None when there is
    no such pair. Squares that under- or overflow take hypot.
    """
    dx, dy, dz = n
    if f == 1.0:
        for k, out in enumerate(n):
            np.subtract(rx[k], tx[k], out=out)
    else:
        for k, out in enumerate(n):
            np.subtract(rx[k] * f, tx[k] * f, out=out)
    np.multiply(dx, dx, out=s)
    np.multiply(dy, dy, out=t)
    s += t
    np.multiply(dz, dz, out=t)
    s += t
    np.sqrt(s, out=r)
    at_tx = None
    if not (s.min() > _SQ_LO and s.max() < _SQ_HI):  # rare: hypot where squares under/overflow
        bad = ~((s > _SQ_LO) & (s < _SQ_HI))
        r[bad] = np.hypot(np.hypot(dx[bad], dy[bad]), dz[bad])
        if not r.min() > 0.0:
            at_tx = r == 0.0
            np.copyto(r, 1.0, where=at_tx)
    dx /= r
    dy /= r
    dz /= r
    return at_tx


def _dipole_direction(tm, n, t, a):
    """u_w = 3 (m.n) n - m, the world-frame field direction, in place of n (returned)."""
    mx, my, mz = tm
    dx, dy, dz = n
    np.multiply(mx, dx, out=t)
    np.multiply(my, dy, out=a)
    t += a
    np.multiply(mz, dz, out=a)
    t += a
    t *= 3.0
    for nk, mk in zip(n, tm):
        nk *= t
        nk -= mk
    return n


def _inner_by_d3(params, noise, dist_scale, g, dense_gz, uw, rr, m1):
    """(flat indices, d3) of a 3-antenna block's inner pairs (d3 <= r_inner).

    Inner pairs are rare: d3 is evaluated only where it can be <= r_inner. Without noise
    |g| <= 2 (to rounding), so d3 >= dist_scale / cbrt(2); with noise, everywhere.
    """
    g0, g1, g2 = g
    shape = g0.shape
    flat = lambda x: x.reshape(-1)  # noqa: E731  (scratch buffers are contiguous)
    if noise is None:
        cand = np.flatnonzero(np.less_equal(dist_scale, params.r_inner * CBRT2_MARGIN, out=m1))
    else:
        cand = np.arange(g0.size)
    if dense_gz:
        gz = flat(g2)[cand]
    else:  # g_z = R_r^T u_w, z row, for the candidates only (same operations)
        ia, ib = np.unravel_index(cand, shape)
        # rr entries are (1, B) or (A, 1) views: index the axis that varies.
        rz = [e[ia, 0] if e.shape[1] == 1 else e[0, ib] for e in (rr[0][2], rr[1][2], rr[2][2])]
        gz = rz[0] * flat(uw[0])[cand] + rz[1] * flat(uw[1])[cand] + rz[2] * flat(uw[2])[cand]
    d3 = flat(dist_scale)[cand] / np.cbrt(norm3(flat(g0)[cand], flat(g1)[cand], gz))
    keep = d3 <= params.r_inner  # |g| == 0 (noise cancelling): d3 = inf, not inner
    return cand[keep], d3[keep]


def _horizontal_distance(g0, g1, dist_scale, s2, t, gxy, dxy):
    """dxy = dist_scale / cbrt(|g_xy|) (|g_xy| the same sums as a safe 2-norm) in ``dxy``;
    |g_xy| == 0 gives inf (or nan): never mid. ``s2``, ``t`` and ``gxy`` are scratch."""
    np.multiply(g0, g0, out=s2)
    np.multiply(g1, g1, out=t)
    s2 += t
    np.sqrt(s2, out=gxy)
    if not (s2.min() > _SQ_LO and s2.max() < _SQ_HI):
        bad = ~((s2 > _SQ_LO) & (s2 < _SQ_HI))
        gxy[bad] = np.hypot(g0[bad], g1[bad])
    np.cbrt(gxy, out=dxy)
    np.divide(dist_scale, dxy, out=dxy)
    return dxy


def _zones(dxy, params, inner_all, zone_out, k_mid, o_out, m2):
    """Zones: mid where dxy <= r_outer, outer elsewhere, inner (sparse) overrides both.

    k_mid = 1 for inner/mid, 0 for outer; o_out = k_mid - 1: an output v becomes
    v * k_mid + o_out, i.e. v itself or -1 (exact: v * 1 + 0, 0 * v - 1).
    """
    le = np.less_equal(dxy, params.r_outer, out=m2)
    np.subtract(2, le.view(np.int8), out=zone_out)
    np.less_equal(dxy, params.r_outer, out=k_mid)
    if inner_all.size:
        k_mid.reshape(-1)[inner_all] = 1.0
        zone_out[np.unravel_index(inner_all, dxy.shape)] = ZONE_INNER
    np.subtract(k_mid, 1.0, out=o_out)


def _write_distance(dist, params, k_mid, o_out, v, d_out):
    """d = round(100 dist) in cm (halves away from zero), -1 for outer pairs."""
    dist *= 100.0
    # floor(x + 0.5) rounds every inner/mid value (cm, >= 0, at most 100 max(r_inner,
    # r_outer)) exactly below 2^52 except x = 0.49999999999999994; outer values become -1.
    if 100.0 * max(params.r_inner, params.r_outer) < 2.0**52 and not np.equal(dist, _BELOW_HALF).any():
        np.add(dist, 0.5, out=v)
        np.floor(v, out=v)
    else:
        np.copyto(v, round_half_away(dist))
    np.fmin(v, 2.0**62, out=v)  # outer pairs may hold inf or nan: keep v * 0 == 0
    v *= k_mid
    v += o_out
    np.copyto(d_out, v, casting="unsafe")


def _write_angle(g0, g1, inner_all, k_mid, o_out, angle, v, mask, delta_out):
    """delta = atan(g_y / g_x) in degrees, rounded half away and clipped to +-89; g_x == 0:
    +-90 with the sign of g_y; 0 for inner pairs, -1 for outer ones."""
    np.divide(g1, g0, out=angle)
    np.arctan(angle, out=angle)
    np.degrees(angle, out=angle)
    zero = np.equal(g0, 0.0, out=mask)
    if zero.any():
        np.copyto(angle, np.copysign(90.0, g1), where=zero)
    # Round half away from zero: trunc(a + copysign(1/2, a)), exact for |a| <= 90 except
    # |a| = 0.49999999999999994 (checked), then clip to +-89.
    np.copysign(0.5, angle, out=v)
    if np.equal(angle, _BELOW_HALF, out=mask).any() or np.equal(angle, -_BELOW_HALF, out=mask).any():
        np.copyto(v, round_half_away(angle))
    else:
        v += angle
        np.trunc(v, out=v)
    np.clip(v, -MAX_DELTA_DEG, MAX_DELTA_DEG, out=v)
    if inner_all.size:
        v.reshape(-1)[inner_all] = 0.0
    v *= k_mid
    v += o_out
    np.copyto(delta_out, v, casting="unsafe")


def _write_field(g, field_scale, at_tx, shape, params, field_out):
    """The receiver-frame field h = field_scale * g, 0 at r = 0 (``at_tx``: the block's
    pairs there, or None), saturated at +-FIELD_SATURATION."""
    if at_tx is None:
        at_tx = np.zeros(shape, dtype=bool)
    for i, gi in enumerate(g):
        h = np.where(gi == 0.0, 0.0, gi * field_scale)
        h[at_tx] = 0.0
        np.clip(h, -FIELD_SATURATION, FIELD_SATURATION, out=field_out[i])
    if params.antennas == 2:
        field_out[2][...] = 0.0  # no z antenna: a 2-antenna unit cannot report h_z


def _add_noise(g0, g1, g2, r, rr, noise, params, want_scale):
    """Add EMI (BRIEF 3.2): h = a u + b v (a = s / (4 pi r^3), b = w_en) with the larger
    of a and b factored out: g = u + (b/a) v at distance scale r * cbrt(kappa_eq / s) when
    b <= a, else g = (a/b) u + v at cbrt(kappa_eq / (4 pi w_en)); b/a may be inf, its
    reciprocal is then 0 and nothing computes inf * 0."""
    q = params.q
    # v = Q R_r^T w_hat: receiver-frame noise, per unit of w_en.
    wx, wy, wz = noise
    v0 = q[0] * (rr[0][0] * wx + rr[1][0] * wy + rr[2][0] * wz)
    v1 = q[1] * (rr[0][1] * wx + rr[1][1] * wy + rr[2][1] * wz)
    v2 = q[2] * (rr[0][2] * wx + rr[1][2] * wy + rr[2][2] * wz)
    # rho = b / a = w_en / (s / (4 pi r^3)) = (2 / max q) (r / r_en)^3; may be inf.
    rho = (2.0 / max(q)) * (r / params.r_en) ** 3
    noise_wins = rho > 1.0
    coef_u = np.where(noise_wins, 1.0 / np.where(noise_wins, rho, 1.0), 1.0)
    coef_v = np.where(noise_wins, 1.0, rho)
    dist_scale = np.where(noise_wins, params.noise_distance, r * params.distance_scale)
    field_scale = None
    if want_scale:
        signal = (params.moment / (4.0 * math.pi)) / r**3
        field_scale = np.where(noise_wins, params.w_en, signal)
    g = tuple(coef_u * gi + coef_v * vi for gi, vi in ((g0, v0), (g1, v1), (g2, v2)))
    return (*g, dist_scale, field_scale)
