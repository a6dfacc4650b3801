"""The fast path of the batch model (issue 20): ideal receiver, 3 antennas, static
transmitters, no field. Same integers as :mod:`emulator.receiver.model.reference`.

Units and frames as there: positions in metres in the world frame (local ENU),
quaternions ``[w, x, y, z]`` body to world, ``d`` in centimetres, ``delta`` in degrees.

Same model, fewer numpy passes: the receiver-frame field direction scaled by
s = |p_r - p_t|^2, G = 3 (m.d) a - s b, needs no sqrt or division; the zone test runs on
(200 dxy)^6 = s^5 / (lam^2 (G_x^2 + G_y^2)), so sqrt, cbrt and atan run only for mid-zone
pairs; per-pose and per-transmitter factors meet in small BLAS products. A pair within
1e-8 of a zone or rounding boundary (1e-6 deg of atan's fold), or where this form could
lose accuracy, goes to the general path pair by pair, so the integers are the general
path's for every pair (tests/emulator/receiver/test_model_fast.py). The derivation, the
accuracy bounds and why numpy rather than C or numexpr: docs/model.md "One fast path,
and the switch".
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np
from numpy.typing import NDArray

from emulator.frames.rotation import rotation_unnormalized_components
from emulator.receiver.model import reference
from emulator.receiver.model.reference import CBRT2_MARGIN, NO_INDEX
from emulator.receiver.model.types import MAX_DELTA_DEG, ZONE_INNER, ZONE_OUTER, Batch, ModelParams, max_abs

_S_LO, _S_HI = 1e-50, 1e50
_CANCEL = 1e5
_Q2_LO, _Q2_HI = 1e-16, 1e290
_RAD2DEG = 180.0 / math.pi
#: Pairs this close to a boundary take the general path (the fast path's own error is
#: ~1e-11 relative): relative on (200 dxy)^6 and 200 d3, absolute in degrees; near +-90
#: degrees the sign of a rounding residue of h_x decides delta's sign.
_EDGE = 1e-8
_DEG_TOL = 1e-7
_FOLD_TOL = 1e-6


class FastTables:
    """Constants and the delta table of the fast path for one ModelParams."""

    def __init__(self, params: ModelParams) -> None:
        c = params.distance_scale
        self.lam = (200.0 * c) ** -3.0
        self.e_mid = (200.0 * params.r_outer) ** 6
        self.e_lo, self.e_hi = self.e_mid * (1.0 - _EDGE), self.e_mid * (1.0 + _EDGE)
        self.d_tol = _EDGE * (100.0 * max(params.r_outer, params.r_inner) + 1.0)  # cm
        self.v_inner = 200.0 * params.r_inner
        # Without noise |g| <= 2 (to rounding): d3 <= r_inner needs s <= this.
        self.s_inner = (params.r_inner * CBRT2_MARGIN / c) ** 2
        k = np.arange(181)  # floor(degrees + 90.5) -> delta
        self.delta = np.clip(k - 90, -MAX_DELTA_DEG, MAX_DELTA_DEG).astype(np.int64)


def applies(batch: Batch) -> bool:
    """Whether the fast path can take this call: no noise, no field, static transmitters,
    a 3-antenna receiver with constants in range."""
    p = batch.params
    if batch.noise is not None or batch.field is not None or batch.moving_tx:
        return False
    return p.antennas == 3 and 1e-6 < p.distance_scale < 1e6 and p.r_inner < 1e6 and p.r_outer < 1e6


class FastPath:
    """The fast path for one ``measure`` call (static transmitters); ``run`` writes its
    poses first..last-1 (threads may run disjoint ranges). ``batch.d`` and ``batch.delta``
    arrive filled with -1: only mid and inner pairs are written."""

    def __init__(self, batch: Batch) -> None:
        self.batch = batch
        self.tab = tables(batch.params)
        with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: those pairs go general
            self.tx = FastTx(batch.tx_p, batch.tx_m, self.tab.lam)
        self.x2 = _square3(max_abs(batch.rx_p)) + self.tx.x2  # bounds |p_r|^2 + |p_t|^2 of every pair

    def run(self, first: int, last: int) -> None:
        """Poses first..last-1 block by block; pairs this path leaves out take the general path."""
        b, rows, m = self.batch, self.batch.rows, self.batch.m
        buf = _fast_buffers(min(last - first, rows), m)
        # Inner-zone candidates and pairs for the general path, of every block (flat
        # indices into the (N, M) outputs): decided once at the end, not per block.
        found, general = [], []
        with np.errstate(all="ignore"):
            for lo in range(first, last, rows):
                sl = slice(lo, min(last, lo + rows))
                bad, cand = _fast_block(b.rx_p[sl], b.rx_q[sl], self.x2, self.tx, self.tab,
                                        b.d[sl], b.delta[sl], b.zone[sl], buf)
                if 4 * bad.size > (sl.stop - sl.start) * m:  # mostly general: the whole block there
                    reference.measure_poses(b, sl.start, sl.stop)
                    continue
                if cand is not None:
                    found.append((lo * m + cand[0],) + cand[1:])
                if bad.size:
                    general.append(lo * m + bad)
            if found:
                general.append(_fast_inner(found, b.rx_p, b.rx_q, self.tx, self.tab, m, b.d, b.delta, b.zone))
        reference.measure_pairs(b, general)


@functools.lru_cache(maxsize=16)
def tables(params: ModelParams) -> FastTables:
    """The fast path's tables for ``params`` (cached: a few hundred KB, built once)."""
    return FastTables(params)


def _fast_block(rx_p, rx_q, x2, tx, tab, d_out, delta_out, zone_out, buf):
    """Poses rx_p (rows, 3), rx_q (rows, 4) against the static transmitters of ``tx``.

    ``x2`` bounds |p_r|^2 + |p_t|^2 for every pair of the block. Outputs (rows, M)
    contiguous; ``d_out`` and ``delta_out`` arrive filled with -1 (only mid pairs are
    written here). Returns the flat indices of the pairs left to the general path (usually
    empty), whose outputs the caller overwrites.
    """
    rows = rx_p.shape[0]
    m = tx.count
    qc = buf.qc[:, :rows]
    np.copyto(qc, rx_q.T)
    # Pose features, feature-major: lay[i] = [R_0i, R_1i, R_2i, (R^T p_r)_i] (4, rows) and
    # pos = [p_r, 1, |p_r|^2] (5, rows); the products below read them transposed (BLAS).
    lay = buf.lay[:, :, :rows]
    pos = buf.pos[:, :rows]
    np.copyto(pos[:3], rx_p.T)
    t = buf.prow[:rows]
    rx2 = pos[4]
    np.multiply(pos[0], pos[0], out=rx2)
    for k in (1, 2):
        np.multiply(pos[k], pos[k], out=t)
        rx2 += t
    # Columns 0 and 1 of R (x and y antennas); column 2 only for inner candidates.
    n2 = rotation_unnormalized_components(qc, lay[:2, :3].transpose(1, 0, 2), buf.pose_work(rows))
    pose_ok = n2.min() > _Q2_LO and n2.max() < _Q2_HI
    pose_bad = None if pose_ok else ~((n2 > _Q2_LO) & (n2 < _Q2_HI))  # before n2's row is reused
    for i in range(2):  # (R^T p_r)_i
        col = lay[i, 3]
        np.multiply(lay[i, 0], pos[0], out=col)
        np.multiply(lay[i, 1], pos[1], out=t)
        col += t
        np.multiply(lay[i, 2], pos[2], out=t)
        col += t
    size = rows * m
    a = buf.a[:, :size].reshape(2, rows, m)
    b = buf.b[:, :size].reshape(2, rows, m)
    md3, s, t = (buf.f[i, :size].reshape(rows, m) for i in range(3))
    feats = lay[:2].transpose(0, 2, 1)
    np.matmul(feats, tx.a_mat, out=a)
    np.matmul(feats, tx.b_mat, out=b)
    np.matmul(pos.T, tx.m_mat, out=md3)
    np.matmul(pos.T, tx.s_mat, out=s)  # |p_r|^2 - 2 p_r.p_t + |p_t|^2 (see _CANCEL)
    s_min, s_max = s.min(), s.max()
    bad = NO_INDEX
    if not (pose_ok and s_min > _S_LO and s_max < _S_HI and x2 <= _CANCEL * s_min):
        scale = np.matmul(pos.T, tx.p2_mat)  # |p_r|^2 + |p_t|^2 (BLAS: no (rows, 1) broadcast)
        ok = (s > _S_LO) & (s < _S_HI) & (scale <= _CANCEL * s)
        if pose_bad is not None:
            ok &= ~pose_bad[:, None]
        bad = np.flatnonzero(~ok)
        if 4 * bad.size > size:  # mostly for the general path: the caller runs the block there
            return bad, None
    a0, a1 = a
    b0, b1 = b
    # G = 3 (m.d) a - s b, scaled by lam (in b and md3), in place of a0, a1.
    g0, g1 = a0, a1
    g0 *= md3
    np.multiply(s, b0, out=t)
    g0 -= t
    g1 *= md3
    np.multiply(s, b1, out=t)
    g1 -= t
    q = b0
    np.multiply(g0, g0, out=q)
    np.multiply(g1, g1, out=t)
    q += t
    e = b1  # (200 dxy)^6 = s^5 / q; q = 0: inf (outer); never nan (s^5 > 0)
    np.multiply(s, s, out=e)
    e *= e
    e *= s
    e /= q
    # Mid zone: (200 dxy)^6 <= (200 r_outer)^6; only those pairs need d and delta. Pairs
    # within EDGE of a zone or rounding boundary (or of atan's fold at +-90) go to the
    # general path, so the integers are the general path's everywhere.
    mask = buf.mask[:size].reshape(rows, m)
    np.less_equal(e, tab.e_hi, out=mask)
    mid = np.flatnonzero(mask)
    np.subtract(ZONE_OUTER, mask.view(np.int8), out=zone_out)  # mid (1) or outer (2)
    if mid.size:
        v = np.take(e.reshape(-1), mid)
        edge = v > tab.e_lo
        np.sqrt(v, out=v)
        np.cbrt(v, out=v)  # 200 dxy
        v += 1.0
        v *= 0.5  # 100 dxy + 1/2
        d_mid = np.floor(v)
        edge |= _near_integer(v, d_mid, tab.d_tol)
        # delta = floor(degrees(atan(g1 / g0)) + 90.5) - 90, clipped to +-89 (a table).
        # Near +-90 (h_x = 0, or a rounding residue whose sign decides) the general path
        # decides, below.
        x = np.take(g0.reshape(-1), mid)
        ang = np.take(g1.reshape(-1), mid)
        ang /= x
        np.arctan(ang, out=ang)
        ang *= _RAD2DEG
        ang += 90.5
        k = np.floor(ang)
        edge |= _near_integer(ang, k, _DEG_TOL)
        ang -= 90.5
        np.abs(ang, out=ang)
        edge |= ang > 90.0 - _FOLD_TOL
        d_out.reshape(-1)[mid] = d_mid.astype(np.int64)
        delta_out.reshape(-1)[mid] = np.take(tab.delta, k.astype(np.intp), mode="clip")
        if edge.any():
            bad = mid[edge] if not bad.size else np.union1d(bad, mid[edge])
    cand = _inner_candidates(s, s_min, q, md3, tab, mask)
    return bad, cand


def _near_integer(x, fl, tol):
    """x within ``tol`` of an integer, given fl = floor(x)."""
    f = x - fl
    return (f < tol) | (f > 1.0 - tol)


def _inner_candidates(s, s_min, q, md3, tab, mask):
    """(flat index, s, q, 3 m.d) of a fast block's pairs that may be inner, or None.

    Only pairs with s <= s_inner can have d3 <= r_inner (|g| <= 2): a few per block,
    decided once per call by :func:`_fast_inner` (pairs that also go to the general path
    are overwritten by it afterwards).
    """
    if not s_min <= tab.s_inner:
        return None
    cand = np.flatnonzero(np.less_equal(s, tab.s_inner, out=mask))
    if not cand.size:
        return None
    return cand, s.reshape(-1)[cand], q.reshape(-1)[cand], md3.reshape(-1)[cand]


def _fast_inner(found, rx_p, rx_q, tx, tab, m, d, delta, zone):
    """Write the inner-zone pairs among the candidates ``found`` (one list per call);
    return the flat indices of those left to the general path.

    For them 200 d3 = (s^5 / (q + G_z^2))^(1/6), G_z = 3 (m.d) a_z - s b_z (scaled like G),
    with the z column of R from the same unnormalised-quaternion formulas.
    """
    cand, s, q, md3 = (np.concatenate(parts) for parts in zip(*found))
    ip, it = np.divmod(cand, m)
    qc = np.ascontiguousarray(rx_q[ip].T)
    rot = np.empty((3, 3, ip.size))
    rotation_unnormalized_components(qc, rot, np.empty((12, ip.size)))
    rz = rot[:, 2]  # R_k2: the z antenna's axis in the world
    a2 = (rz * (rx_p[ip] - tx.p[it]).T).sum(axis=0)
    bz = (rz * tx.b_mat[:3, it]).sum(axis=0)
    gz = md3 * a2 - s * bz
    v3 = np.cbrt(np.sqrt(s * s * s * s * s / (q + gz * gz)))  # 200 d3
    w = (v3 + 1.0) * 0.5  # 100 d3 + 1/2
    fl = np.floor(w)
    edge = (np.abs(v3 - tab.v_inner) <= _EDGE * tab.v_inner) | _near_integer(w, fl, tab.d_tol)
    keep = (v3 <= tab.v_inner) & ~edge
    idx = cand[keep]
    d.reshape(-1)[idx] = fl[keep].astype(np.int64)
    delta.reshape(-1)[idx] = 0
    zone.reshape(-1)[idx] = ZONE_INNER
    return cand[edge]  # near the inner boundary or a rounding point: the general path decides


def _square3(x: float) -> float:
    """3 x^2 (an upper bound of |p|^2 for coordinates up to x), inf instead of overflowing."""
    return 3.0 * x * x if x < 1e150 else math.inf


class FastTx:
    """Per-transmitter matrices of the fast path (static transmitters (M, 3), axes (3, M))."""

    def __init__(self, tx_p, tx_m, lam: float) -> None:
        self.count = m = tx_p.shape[0]
        self.p = tx_p
        # a_i = [R_0i, R_1i, R_2i, (R^T p_r)_i] . [-p_t, 1]
        self.a_mat = np.ascontiguousarray(np.vstack([-tx_p.T, np.ones((1, m))]))
        # b_i = lam [R_0i, R_1i, R_2i, .] . [m, 0]
        self.b_mat = np.ascontiguousarray(np.vstack([lam * tx_m, np.zeros((1, m))]))
        # 3 lam m.(p_r - p_t) = [p_r, 1, |p_r|^2] . [3 lam m, -3 lam m.p_t, 0]
        mt = np.einsum("km,mk->m", tx_m, tx_p)
        self.m_mat = np.ascontiguousarray(np.vstack([3.0 * lam * tx_m, -3.0 * lam * mt[None, :], np.zeros((1, m))]))
        self.p2 = np.sum(tx_p * tx_p, axis=1)
        # |p_r|^2 + |p_t|^2 = [p_r, 1, |p_r|^2] . [0, |p_t|^2, 1]
        self.p2_mat = np.ascontiguousarray(np.vstack([np.zeros((3, m)), self.p2[None, :], np.ones((1, m))]))
        # s = |p_r - p_t|^2 = [p_r, 1, |p_r|^2] . [-2 p_t, |p_t|^2, 1]
        self.s_mat = np.ascontiguousarray(np.vstack([-2.0 * tx_p.T, self.p2[None, :], np.ones((1, m))]))
        self.x2 = _square3(float(np.max(np.abs(tx_p), initial=0.0)))


_LOCAL = threading.local()


def _fast_buffers(rows: int, m: int) -> "_FastBuffers":
    """This thread's fast-path scratch, reused across calls (a few MB, touched once)."""
    buf = getattr(_LOCAL, "fast", None)
    if buf is None or buf.rows < rows or buf.size < rows * m:
        buf = _LOCAL.fast = _FastBuffers(max(rows, 1), m)
    return buf


class _FastBuffers:
    """Scratch of the fast path for blocks of up to ``rows`` poses x ``m`` transmitters."""

    def __init__(self, rows: int, m: int) -> None:
        size = rows * m
        self.rows, self.size = rows, size
        self.qc = np.empty((4, rows))
        # The per-pose work (12 rows) shares the pair buffers (used only after it) when they fit.
        self.qwork = None if 3 * size >= 12 * rows else np.empty((12, rows))
        self.lay = np.empty((2, 4, rows))
        self.prow = np.empty(rows)
        self.pos = np.ones((5, rows))
        self.a = np.empty((2, size))
        self.b = np.empty((2, size))
        self.f = np.empty((3, size))
        self.mask = np.empty(size, dtype=bool)

    def pose_work(self, rows: int) -> NDArray[np.float64]:
        """(12, rows) scratch for the rotations (overwritten by the block's products)."""
        if self.qwork is not None:
            return self.qwork[:, :rows]
        return self.f.reshape(-1)[: 12 * rows].reshape(12, rows)
