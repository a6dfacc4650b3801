"""The receiver model of BRIEF section 3: field, zones and (d, delta) for N x M pairs.

Frames (BRIEF 2): world = local ENU in metres; body x forward, y left, z up; the
transmitter dipole points along its +x; quaternions ``[w, x, y, z]`` rotate body into world.

Numerical formulation (BRIEF 3.3). With p = R_t^T (p_r - p_t), r = |p| (a norm that
neither under- nor overflows) and the unit direction p/r = (x, y, z), the field is

    h = s / (4 pi r^3) * u,    u = R_r^T R_t [2x^2 - y^2 - z^2, 3xy, 3xz],   1 <= |u| <= 2

computed as u = R_r^T (3 x n - m) with n = (p_r - p_t)/r in the world and m = R_t e_x
the dipole axis (the same vector: [2x^2-y^2-z^2, 3xy, 3xz] = 3x(x, y, z) - e_x),

so without noise every output follows from u and r alone:

    d3  = r * cbrt(kappa_eq / s) / cbrt(|u|)
    dxy = r * cbrt(kappa_eq / s) / cbrt(|(u_x, u_y)|)
    delta = atan(u_y / u_x)

and no intermediate over- or underflows for any finite r > 0.

Receiver classes (``ModelParams.antennas``). A 3-antenna receiver (the default, BRIEF 3)
takes d3 in the inner zone and dxy outside it. A 2-antenna receiver has only the two
horizontal antennas: every zone uses dxy (inner when dxy <= r_inner, delta 0; mid when
dxy <= r_outer; outer otherwise, and (h_x, h_y) = (0, 0) is outer: directly above a
vertical transmitter it reads no signal, the 2-antenna "spike"). r = 0 exactly is inner
with (0, 0) for both classes. The same scale-free g, so the same stability.

With noise, h = a u + b v
(a = s/(4 pi r^3), b = w_en, v = Q R_r^T w/w_en, |w/w_en| <= 1). We factor out the larger
of a and b: g = u + (b/a) v with distance scale r * cbrt(kappa_eq/s) when b <= a, else
g = (a/b) u + v with scale cbrt(kappa_eq / (4 pi w_en)). The ratio b/a = (2/max q)(r/r_en)^3
may overflow to inf; its reciprocal is then 0 and nothing ever computes inf * 0.
"""

from __future__ import annotations

import functools
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import InputError, PoseError

from emulator.frames.rotation import (
    normalize_components_inplace,
    rotation_components,
    rotation_unnormalized_components,
    unit_quaternion_components,
    x_axis_components,
)

try:  # the fast path as one compiled loop (setup.py builds it when a C compiler is present)
    from emulator.receiver import model_kernel
except ImportError:  # not built: the numpy fast path runs
    model_kernel = None

ZONE_INNER, ZONE_MID, ZONE_OUTER = 0, 1, 2
ZONE_NAMES = ("inner", "mid", "outer")
#: Receiver classes the model knows: antennas used for the distance (2: horizontal pair).
ANTENNAS = (2, 3)
MAX_DELTA_DEG = 89
#: Largest magnitude a $PARVH component can carry; fields beyond it (r below ~1e-103 m)
#: saturate here rather than print ``inf``.
FIELD_SATURATION = float(np.finfo(np.float64).max)
#: Pairs are evaluated in blocks of about this many, reusing 12 float scratch buffers per
#: block (3 MB: about the L2 of the 2-core Xeon here); smaller blocks pay more per-call
#: overhead than they win in cache hits (tests/perf/bench_model.py, docs/performance.md).
CHUNK_PAIRS = 1 << 15
_HUGE = 2.0**1020  # ~1.1e307
#: Which implementation runs the fast path (ideal 3-antenna receiver, static transmitters,
#: no field): "compiled" (emulator/receiver/model_kernel.c, an optional extension built
#: by ``pip install``), "numpy" (the numpy passes of _fast_block) or "auto" (compiled when
#: built, else numpy). Set from the environment variable ARVA_MODEL_KERNEL at import; both
#: give the same integers (every pair either path leaves undecided takes the general path).
KERNEL = os.environ.get("ARVA_MODEL_KERNEL", "auto")
KERNELS = ("auto", "compiled", "numpy")
#: Whether the compiled kernel was built (and imported) in this installation.
KERNEL_BUILT = model_kernel is not None


@dataclass(frozen=True)
class ModelParams:
    """Receiver/transmitter constants (BRIEF 3). Lengths in metres.

    ``moment`` is s = kappa |m| in scene units; ``kappa_eq`` is in the same units (with
    s = 1 the estimate is 0.917 r on the dipole axis, 1.155 r broadside).
    """

    kappa_eq: float = 1.542
    moment: float = 1.0
    r_inner: float = 3.0
    r_outer: float = 50.0
    r_en: float = 80.0
    q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: Receiver class: 3 (d3 in the inner zone, BRIEF 3) or 2 (horizontal antennas only:
    #: dxy in every zone). See the module docstring.
    antennas: int = 3

    def __post_init__(self) -> None:
        if isinstance(self.antennas, bool) or self.antennas not in ANTENNAS:
            raise InputError(f"receiver.antennas: must be 2 or 3, got {self.antennas!r}")
        for name in ("kappa_eq", "moment", "r_inner", "r_outer", "r_en"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"model.{name}: must be a finite number > 0, got {value!r}")
        if len(self.q) != 3 or not all(isinstance(v, (int, float)) and 0 < v <= 1 for v in self.q):
            raise InputError(f"model.q: must be 3 numbers in (0, 1], got {list(self.q)!r}")
        scale = math.cbrt(self.kappa_eq / self.moment)
        if not (math.isfinite(scale) and scale > 0):
            raise InputError("model: kappa_eq / moment must be a finite positive ratio")

    @property
    def distance_scale(self) -> float:
        """cbrt(kappa_eq / s): the d3 of a unit field direction at r = 1 m."""
        return math.cbrt(self.kappa_eq / self.moment)

    @property
    def w_en(self) -> float:
        """Radius of the EMI noise ball, s / (2 pi max(q) r_en^3) (paper eq. 5)."""
        return self.moment / (2.0 * math.pi * max(self.q) * self.r_en**3)

    @property
    def noise_distance(self) -> float:
        """cbrt(kappa_eq / (4 pi w_en)): d3 for a field of magnitude w_en."""
        return math.cbrt(self.kappa_eq / (4.0 * math.pi * self.w_en))


@dataclass
class Measurement:
    """What a receiver computes for each (pose, transmitter) pair, arrays of shape (N, M).

    ``d`` in centimetres and ``delta`` in degrees (int64; -1, -1 in the outer zone);
    ``zone`` is ZONE_INNER / ZONE_MID / ZONE_OUTER; ``field`` (N, M, 3), only when asked
    for, is the receiver-frame field in scene units (saturated at +-FIELD_SATURATION;
    its z component is 0 for a 2-antenna receiver, which has no z antenna).
    """

    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    zone: NDArray[np.int8]
    field: NDArray[np.float64] | None = None


def round_half_away(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Round to the nearest integer, halves away from zero (not banker's rounding).

    ``x - trunc(x)`` is exact in binary floating point, so 0.49999999999999994 stays 0
    (``floor(x + 0.5)`` would give 1).
    """
    t = np.trunc(x)
    return t + np.where(np.abs(x - t) >= 0.5, np.sign(x), 0.0)


# Squares of components between these bounds neither underflow nor overflow, so the
# plain sqrt of the sum of squares is exact to an ulp; outside them we fall back to
# hypot (slow but safe). This keeps the common case 4x faster than hypot everywhere.
_SQ_LO, _SQ_HI = 1e-290, 1e290


def norm3(x, y, z):
    """Euclidean norm of (x, y, z), element-wise, without under- or overflow."""
    with np.errstate(over="ignore", under="ignore"):
        s = x * x + y * y + z * z
    r = np.sqrt(s)
    bad = ~((s > _SQ_LO) & (s < _SQ_HI))
    if bad.any():
        r[bad] = np.hypot(np.hypot(x[bad], y[bad]), z[bad])
    return r


def norm2(x, y):
    """Euclidean norm of (x, y), element-wise, without under- or overflow."""
    with np.errstate(over="ignore", under="ignore"):
        s = x * x + y * y
    r = np.sqrt(s)
    bad = ~((s > _SQ_LO) & (s < _SQ_HI))
    if bad.any():
        r[bad] = np.hypot(x[bad], y[bad])
    return r


def as_positions(p: ArrayLike, field_name: str) -> NDArray[np.float64]:
    """float64 positions (..., 3); non-finite values are a :class:`PoseError`."""
    p = np.asarray(p, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise PoseError(field_name, f"a position has 3 components [x, y, z], got shape {p.shape}")
    if not _all_finite(p):
        raise PoseError(field_name, "position has a non-finite component")
    return p


def measure(
    rx_position: ArrayLike,
    rx_orientation: ArrayLike,
    tx_position: ArrayLike,
    tx_orientation: ArrayLike,
    params: ModelParams = ModelParams(),
    noise: NDArray[np.float64] | None = None,
    want_field: bool = False,
    threads: int = 1,
) -> Measurement:
    """Evaluate N receiver poses against M transmitters.

    ``rx_position`` (N, 3) and ``rx_orientation`` (N, 4); ``tx_position`` (M, 3) or
    (N, M, 3) and ``tx_orientation`` (M, 4) or (N, M, 4) for moving transmitters.
    Quaternions need not be normalised. ``noise``, when given, is (N, M, 3) points of
    the unit ball in the world frame (see :mod:`emulator.receiver.noise`); they are scaled by
    ``params.w_en`` and mapped by Q R_r^T (BRIEF 3.2). ``noise=None`` is the ideal
    receiver and costs nothing extra. ``params.antennas`` selects the receiver class
    (3: BRIEF 3; 2: the horizontal field in every zone, see the module docstring).
    ``threads`` > 1 splits the poses into that many contiguous ranges evaluated in
    parallel threads (same results; worth it only for large N on idle cores).
    """
    rx_p = as_positions(rx_position, "receiver.position")
    tx_p = as_positions(tx_position, "transmitter.position")
    # Component-major (see emulator.frames.rotation): receiver matrices (3, 3, N), transmitter
    # dipole axes (3, M) or (3, N, M).
    # Receiver matrices are built per chunk (in cache); the quaternions are checked here.
    rx_q = _quaternions(rx_orientation, "receiver.orientation")
    try:
        tx_m = x_axis_components(unit_quaternion_components(tx_orientation, "transmitter.orientation"))
    except PoseError:
        unit_quaternion_components(rx_q, "receiver.orientation")  # a receiver error comes first
        raise
    n = rx_p.shape[0]
    m = tx_p.shape[-2]
    moving_tx = tx_p.ndim == 3 or tx_m.ndim == 3
    if moving_tx:
        tx_p = np.broadcast_to(tx_p, (n, m, 3))
        tx_m = np.broadcast_to(tx_m if tx_m.ndim == 3 else tx_m[:, None, :], (3, n, m))
    fld = np.empty((n, m, 3)) if want_field else None
    fast = noise is None and fld is None and not moving_tx and _FastTables.applies(params)
    compiled = _compiled_kernel() and fast  # the switch is checked on every call
    if compiled:  # the kernel writes every pair's d, delta and zone
        d = np.empty((n, m), dtype=np.int64)
        delta = np.empty((n, m), dtype=np.int64)
    elif fast:
        # The fast path writes d and delta of the mid (and inner) pairs only: the rest are
        # -1, filled here in one pass over the whole (fresh) array rather than block by
        # block (in-process A/B on 1e6 poses x 4 tx: 1-3 ns/pair less; the first touch of
        # the fresh pages streams better in one pass).
        d = np.full((n, m), -1, dtype=np.int64)
        delta = np.full((n, m), -1, dtype=np.int64)
    else:
        d = np.empty((n, m), dtype=np.int64)
        delta = np.empty((n, m), dtype=np.int64)
    zone = np.empty((n, m), dtype=np.int8)
    if n == 0 or m == 0:
        return Measurement(d, delta, zone, fld)
    # Layout of a chunk: a 2-D block whose inner (contiguous) axis is the longer of poses
    # and transmitters, so every ufunc runs long contiguous loops with per-pose or
    # per-transmitter values broadcast as scalars along it.
    tx_major = n >= m
    rows = max(1, CHUNK_PAIRS // m)
    # Coordinates beyond ~1e307 could overflow a difference: a chunk holding any is scaled
    # by an exact power of two (decided per chunk, as before, see _measure_chunk).
    # (Only the general path needs it, so it is found when first asked for.)
    @functools.cache
    def any_big() -> bool:
        return max(_max_abs(rx_p), _max_abs(tx_p)) > _HUGE

    if compiled:
        tab = _tables(params)
        with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: those pairs go general
            ktx = _kernel_tx(tx_p, tx_m, tab.lam)
        rx_pc, rx_qc = np.ascontiguousarray(rx_p), np.ascontiguousarray(rx_q)
    elif fast:
        tab = _tables(params)
        with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates: those pairs go general
            ftx = _FastTx(tx_p, tx_m, tab.lam)
        x2 = _square3(_max_abs(rx_p)) + ftx.x2  # bounds |p_r|^2 + |p_t|^2 of every pair

    def run_compiled(first: int, last: int) -> None:
        """Like ``run_fast``, each block in one call of the compiled kernel (no GIL held)."""
        general = []
        for lo in range(first, last, rows):
            hi = min(last, lo + rows)
            count = model_kernel.fast_pairs(rx_pc[lo:hi], rx_qc[lo:hi], ktx, tab.kernel_consts,
                                             d[lo:hi], delta[lo:hi], zone[lo:hi])
            if 4 * count > (hi - lo) * m:  # mostly general: the whole block there
                run_general(lo, hi)
            elif count:
                general.append(lo * m + np.flatnonzero(zone[lo:hi].reshape(-1) < 0))
        run_general_pairs(general)

    def run_fast(first: int, last: int) -> None:
        """Like ``run`` on the fast path; pairs it leaves out take the general path."""
        buf = _fast_buffers(min(last - first, rows), m)
        # Inner-zone candidates and pairs for the general path, of every block (flat
        # indices into the (N, M) outputs): decided once at the end, not per block.
        found, general = [], []
        with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
            for lo in range(first, last, rows):
                sl = slice(lo, min(last, lo + rows))
                bad, cand = _fast_block(rx_p[sl], rx_q[sl], x2, ftx, tab, d[sl], delta[sl], zone[sl], buf)
                if 4 * bad.size > (sl.stop - sl.start) * m:  # mostly general: the whole block there
                    run_general(sl.start, sl.stop)
                    continue
                if cand is not None:
                    found.append((lo * m + cand[0],) + cand[1:])
                if bad.size:
                    general.append(lo * m + bad)
            if found:
                general.append(_fast_inner(found, rx_p, rx_q, ftx, tab, m, d, delta, zone))
        run_general_pairs(general)

    def run_general_pairs(general: list) -> None:
        """The pairs a fast path left undecided (lists of flat indices) on the general path."""
        flat = np.concatenate(general) if general else _NO_INDEX
        with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
            for lo in range(0, flat.size, CHUNK_PAIRS):  # in blocks: all pairs may be here
                part = flat[lo:lo + CHUNK_PAIRS]
                ip, it = np.divmod(part, m)
                out = _general_pairs(rx_p, rx_q, ip, tx_p, tx_m, it, params)
                for arr, val in zip((d, delta, zone), out):
                    arr.reshape(-1)[part] = val

    def run(first: int, last: int) -> None:
        """Poses first..last-1, block by block, with this call's own buffers."""
        if compiled:
            return run_compiled(first, last)
        if fast:
            return run_fast(first, last)
        return run_general(first, last)

    def run_general(first: int, last: int) -> None:
        """``run`` on the general path (the formulation of _measure_chunk)."""
        size = min(last - first, rows)
        scratch = _Scratch(size * m)
        rot = np.empty((3, 3, size))
        q_rows, q_work = np.empty((4, size)), np.empty((4, size))
        with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
            for lo in range(first, last, rows):
                hi = min(last, lo + rows)
                sl = slice(lo, hi)
                if tx_major:  # (M, rows): per pose (1, rows), per transmitter (M, 1)
                    pose = lambda a: a[None, :]  # noqa: E731
                    pair = lambda a: a.T  # noqa: E731  (rows, M) -> (M, rows)
                    txv = lambda a: a[:, None]  # noqa: E731
                else:  # (rows, M): per pose (rows, 1), per transmitter (1, M)
                    pose = lambda a: a[:, None]  # noqa: E731
                    pair = lambda a: a  # noqa: E731
                    txv = lambda a: a[None, :]  # noqa: E731
                if moving_tx:
                    tx_x, tx_y, tx_z = (pair(tx_p[sl, :, k]) for k in range(3))
                    mx, my, mz = (pair(tx_m[k, sl]) for k in range(3))
                else:
                    tx_x, tx_y, tx_z = (txv(tx_p[:, k]) for k in range(3))
                    mx, my, mz = (txv(tx_m[k]) for k in range(3))
                f = 1.0
                if any_big():
                    big = max(np.max(np.abs(rx_p[sl]), initial=0.0),
                              np.max(np.abs(tx_p[sl] if moving_tx else tx_p), initial=0.0)) > _HUGE
                    f = 0.25 if big else 1.0
                qc = q_rows[:, : hi - lo]
                np.copyto(qc, rx_q[sl].T)
                if normalize_components_inplace(qc, q_work[:, : hi - lo]) is not None:
                    # report it as for the whole array (e.g. its smallest norm)
                    unit_quaternion_components(rx_q, "receiver.orientation")
                rx_r = rotation_components(qc, out=rot[:, :, : hi - lo])
                _measure_chunk(
                    tuple(pose(rx_c) for rx_c in np.ascontiguousarray(rx_p[sl].T)),
                    tuple(tuple(pose(rx_r[i, j]) for j in range(3)) for i in range(3)),
                    (tx_x, tx_y, tx_z),
                    (mx, my, mz),
                    f,
                    params,
                    None if noise is None else tuple(pair(noise[sl, :, k]) for k in range(3)),
                    pair(d[sl]),
                    pair(delta[sl]),
                    pair(zone[sl]),
                    None if fld is None else tuple(pair(fld[sl, :, k]) for k in range(3)),
                    scratch.view((m, hi - lo) if tx_major else (hi - lo, m)),
                )

    parts = max(1, min(int(threads), -(-n // rows)))
    if parts == 1:
        run(0, n)
    else:  # numpy releases the GIL inside its loops: disjoint slices of the outputs
        step = -(-n // (parts * rows)) * rows
        with ThreadPoolExecutor(max_workers=parts) as pool:
            for job in [pool.submit(run, lo, min(n, lo + step)) for lo in range(0, n, step)]:
                job.result()  # re-raises a worker's error (e.g. a PoseError)
    return Measurement(d, delta, zone, fld)


def _general_pairs(rx_p, rx_q, ip, tx_p, tx_m, it, params):
    """(d, delta, zone) of the pairs (rx ip[k], tx it[k]) on the general path (1-D)."""
    k = ip.size
    qc = np.ascontiguousarray(rx_q[ip].T)
    if normalize_components_inplace(qc, np.empty_like(qc)) is not None:
        unit_quaternion_components(rx_q, "receiver.orientation")  # as for the whole array
    rr = rotation_components(qc)
    row = lambda a: a.reshape(1, k)  # noqa: E731
    rx = tuple(row(rx_p[ip, c]) for c in range(3))
    tx = tuple(row(tx_p[it, c]) for c in range(3))
    big = max(_max_abs(np.stack(rx)), _max_abs(np.stack(tx))) > _HUGE
    out = (np.empty((1, k), np.int64), np.empty((1, k), np.int64), np.empty((1, k), np.int8))
    with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
        _measure_chunk(rx, tuple(tuple(row(rr[i, j]) for j in range(3)) for i in range(3)), tx,
                       tuple(row(tx_m[c, it]) for c in range(3)), 0.25 if big else 1.0, params, None,
                       *out, None, _Scratch(k).view((1, k)))
    return tuple(o.reshape(-1) for o in out)


_TABLES: dict = {}


def _tables(params: ModelParams) -> "_FastTables":
    """The fast path's tables for ``params`` (cached: a few hundred KB, built once)."""
    tab = _TABLES.get(params)
    if tab is None:
        if len(_TABLES) > 16:
            _TABLES.clear()
        tab = _TABLES[params] = _FastTables(params)
    return tab


def _max_abs(a: NDArray[np.float64]) -> float:
    """max |a| without an |a| temporary (0 for an empty array)."""
    return max(float(a.max(initial=0.0)), -float(a.min(initial=0.0)))


def _all_finite(a: NDArray[np.float64]) -> bool:
    """No NaN or infinity in ``a``: its sum is finite (one pass, no temporary), or every
    element is (the sum of finite values may overflow)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if math.isfinite(np.sum(a)):
            return True
    return bool(np.all(np.isfinite(a)))


def _quaternions(q: ArrayLike, field: str) -> NDArray[np.float64]:
    """float64 quaternions (N, 4) with shape and finiteness checked (norms: per chunk)."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,) or not _all_finite(q):
        unit_quaternion_components(q, field)  # raises the PoseError naming the field
    return q


class _Scratch:
    """Preallocated float64 and bool buffers for one chunk (reused by every chunk)."""

    FLOATS, BOOLS = 12, 3

    def __init__(self, size: int) -> None:
        self.f = np.empty((self.FLOATS, size))
        self.b = np.empty((self.BOOLS, size), dtype=bool)

    def view(self, shape: tuple[int, int]) -> tuple[list, list]:
        size = shape[0] * shape[1]
        return ([a[:size].reshape(shape) for a in self.f], [a[:size].reshape(shape) for a in self.b])


def _measure_chunk(rx, rr, tx, tm, f, params, noise, d_out, delta_out, zone_out, field_out, scratch):
    """One block of pairs. Every array argument broadcasts to the block's 2-D shape.

    Only the dipole axis m = R_t e_x (first column of R_t) matters: with n the world unit
    vector from transmitter to receiver and x = m.n (the transmitter-frame x of p/r),
    A(p)/r^2 = 3 x (p/r) - e_x in the transmitter frame, i.e. u_w = 3 x n - m in the
    world frame. Same field as eq. 1 rotated by R_t, in 3x fewer operations.

    Written with ``out=`` into preallocated buffers and in-place ufuncs (no temporaries
    on the common path) and the same floating-point operations in the same order as the
    plain formulas, so the results are bit for bit those of the straightforward version.
    A chunk whose coordinates exceed ~1e307 arrives with f = 1/4 (exact for normal floats):
    differences are scaled down and distances back up (to inf: outer).
    """
    (dx, dy, dz, r, t, g0, g1, g2, a, b, k_mid, o_out), (m1, m2, m3) = scratch
    shape = dx.shape
    flat = lambda x: x.reshape(-1)  # noqa: E731  (scratch buffers are contiguous)
    mx, my, mz = tm
    # p_r - p_t and its safe norm.
    if f == 1.0:
        for k, out in enumerate((dx, dy, dz)):
            np.subtract(rx[k], tx[k], out=out)
    else:
        for k, out in enumerate((dx, dy, dz)):
            np.subtract(rx[k] * f, tx[k] * f, out=out)
    s = a
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
    # n = (p_r - p_t) / r, x3 = 3 m.n, u_w = x3 n - m (in place of n).
    dx /= r
    dy /= r
    dz /= r
    r_safe = r if f == 1.0 else r / f  # true distance; inf only for pairs ~1e308 m apart
    np.multiply(mx, dx, out=t)
    np.multiply(my, dy, out=a)
    t += a
    np.multiply(mz, dz, out=a)
    t += a
    t *= 3.0
    for nk, mk in ((dx, mx), (dy, my), (dz, mz)):
        nk *= t
        nk -= mk
    uw = (dx, dy, dz)
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

    # Inner pairs are rare: d3 is evaluated only where it can be <= r_inner. Without noise
    # |g| <= 2 (to rounding), so d3 >= dist_scale / cbrt(2); with noise, everywhere.
    at_idx = np.flatnonzero(at_tx) if at_tx is not None else _NO_INDEX
    if three:
        if noise is None:
            cand = np.flatnonzero(np.less_equal(dist_scale, params.r_inner * _CBRT2_MARGIN, out=m1))
        else:
            cand = np.arange(dx.size)
        if dense_gz:
            gz = flat(g2)[cand]
        else:  # g_z = R_r^T u_w, z row, for the candidates only (same operations)
            ia, ib = np.unravel_index(cand, shape)
            # rr entries are (1, B) or (A, 1) views: index the axis that varies.
            rz = [e[ia, 0] if e.shape[1] == 1 else e[0, ib] for e in (rr[0][2], rr[1][2], rr[2][2])]
            gz = rz[0] * flat(uw[0])[cand] + rz[1] * flat(uw[1])[cand] + rz[2] * flat(uw[2])[cand]
        d3 = flat(dist_scale)[cand] / np.cbrt(norm3(flat(g0)[cand], flat(g1)[cand], gz))
        keep = d3 <= params.r_inner  # |g| == 0 (noise cancelling): d3 = inf, not inner
        inner_idx, inner_d3 = cand[keep], d3[keep]
    # |g_xy| (the same sums as norm2).
    s2 = dx
    np.multiply(g0, g0, out=s2)
    np.multiply(g1, g1, out=t)
    s2 += t
    gxy = np.sqrt(s2, out=dz)
    if not (s2.min() > _SQ_LO and s2.max() < _SQ_HI):
        bad = ~((s2 > _SQ_LO) & (s2 < _SQ_HI))
        gxy[bad] = np.hypot(g0[bad], g1[bad])
    dxy = np.cbrt(gxy, out=a)
    np.divide(dist_scale, dxy, out=dxy)  # gxy == 0: inf (or nan): never mid
    if not three:  # 2 antennas: the horizontal field in every zone
        inner_idx = np.flatnonzero(np.less_equal(dxy, params.r_inner, out=m1))
    inner_all = np.concatenate((inner_idx, at_idx)) if at_idx.size else inner_idx
    # Zones: mid where dxy <= r_outer, outer elsewhere, inner (sparse) overrides both.
    # k_mid = 1 for inner/mid, 0 for outer; o_out = k_mid - 1: an output v becomes
    # v * k_mid + o_out, i.e. v itself or -1 (exact: v * 1 + 0, 0 * v - 1).
    le = np.less_equal(dxy, params.r_outer, out=m2)
    np.subtract(2, le.view(np.int8), out=zone_out)
    np.less_equal(dxy, params.r_outer, out=k_mid)
    if inner_all.size:
        flat(k_mid)[inner_all] = 1.0
        zone_out[np.unravel_index(inner_all, shape)] = ZONE_INNER
    np.subtract(k_mid, 1.0, out=o_out)

    dist = dxy
    if three and inner_idx.size:
        flat(dist)[inner_idx] = inner_d3
    if at_idx.size:
        flat(dist)[at_idx] = 0.0
    dist *= 100.0
    v = t
    if _round_half_up_exact(dist, params):
        np.add(dist, 0.5, out=v)
        np.floor(v, out=v)
    else:
        np.copyto(v, round_half_away(dist))
    np.fmin(v, 2.0**62, out=v)  # outer pairs may hold inf or nan: keep v * 0 == 0
    v *= k_mid
    v += o_out
    np.copyto(d_out, v, casting="unsafe")

    # delta = atan(g_y / g_x) in degrees; g_x == 0: +-90 with the sign of g_y.
    angle = np.divide(g1, g0, out=a)
    np.arctan(angle, out=angle)
    np.degrees(angle, out=angle)
    zero = np.equal(g0, 0.0, out=m3)
    if zero.any():
        np.copyto(angle, np.copysign(90.0, g1), where=zero)
    # Round half away from zero: trunc(a + copysign(1/2, a)), exact for |a| <= 90 except
    # |a| = 0.49999999999999994 (checked), then clip to +-89.
    v = np.copysign(0.5, angle, out=t)
    if np.equal(angle, _BELOW_HALF, out=m3).any() or np.equal(angle, -_BELOW_HALF, out=m3).any():
        np.copyto(v, round_half_away(angle))
    else:
        v += angle
        np.trunc(v, out=v)
    np.clip(v, -MAX_DELTA_DEG, MAX_DELTA_DEG, out=v)
    if inner_all.size:
        flat(v)[inner_all] = 0.0
    v *= k_mid
    v += o_out
    np.copyto(delta_out, v, casting="unsafe")

    if field_out is not None:
        if at_tx is None:
            at_tx = np.zeros(r.shape, dtype=bool)
        for i, g in enumerate((g0, g1, g2)):
            h = np.where(g == 0.0, 0.0, g * field_scale)
            h[at_tx] = 0.0
            np.clip(h, -FIELD_SATURATION, FIELD_SATURATION, out=field_out[i])
        if params.antennas == 2:
            field_out[2][...] = 0.0  # no z antenna: a 2-antenna unit cannot report h_z


#: Without noise |g| <= 2 up to a few ulps: d3 <= r_inner needs dist_scale <= r_inner * this.
_CBRT2_MARGIN = math.cbrt(2.0) * (1.0 + 1e-9)
#: The one x in [0, 2^52) with floor(x + 0.5) != round-half-away(x) (x + 0.5 rounds up to 1).
_BELOW_HALF = 0.49999999999999994
_NO_INDEX = np.empty(0, dtype=np.intp)


def _round_half_up_exact(x, params) -> bool:
    """True when floor(x + 0.5) rounds every inner/mid value of ``x`` (cm, >= 0) exactly.

    Such values are <= 100 max(r_inner, r_outer); floor(x + 0.5) is exact below 2^52
    except at x = 0.49999999999999994. Outer values (any) are replaced by -1 later.
    """
    if 100.0 * max(params.r_inner, params.r_outer) >= 2.0**52:
        return False
    return not np.equal(x, _BELOW_HALF).any()


def _add_noise(g0, g1, g2, r, rr, noise, params, want_scale):
    """Add EMI (BRIEF 3.2) in the scaled form described in the module docstring."""
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
    return (
        coef_u * g0 + coef_v * v0,
        coef_u * g1 + coef_v * v1,
        coef_u * g2 + coef_v * v2,
        dist_scale,
        field_scale,
    )


# ---------------------------------------------------------------------------------------
# Fast path (issue 20): ideal receiver, 3 antennas, static transmitters, no field.
#
# Same model, fewer numpy passes. With d = p_r - p_t, s = |d|^2 and a, b the receiver-frame
# d and dipole axis (a = R_r^T d, b = R_r^T m), the receiver-frame field direction scaled
# by s is G = 3 (m.d) a - s b (= s g: no sqrt, no division per component), and
#
#     (200 dxy)^6 = s^5 / (lam^2 (G_x^2 + G_y^2)),   lam = (200 c)^-3,  c = distance_scale
#
# (lam is folded into b and m.d, so the scaled G costs nothing extra). a_x, a_y, b_x, b_y,
# 3 m.d and s = |p_r|^2 - 2 p_r.p_t + |p_t|^2 are bilinear in per-pose and
# per-transmitter values: one small BLAS product each (K = 4 or 5) instead of five numpy
# passes. The zone test is on (200 dxy)^6 against (200 r_outer)^6, so sqrt, cbrt and atan
# run only for the mid-zone pairs (gathered); d = floor((200 dxy + 1) / 2) and delta =
# floor(degrees(atan(G_y / G_x)) + 90.5) - 90 (clipped, a table). Inner pairs are rare and
# found from s alone (|g| <= 2). Rounding and zone tests thus happen on different but
# equivalent expressions, good to ~1e-11 (relative); a pair within 1e-8 of a zone or
# rounding boundary (or 1e-6 degrees of atan's fold at +-90) is handed to the general
# path, so the integers are the general path's for every pair
# (tests/test_model_fast.py: millions of random pairs, hairs from each boundary).
#
# Pairs where this formulation could lose accuracy go to the general path, pair by pair
# (so the result of a pair never depends on its block): s outside [1e-50, 1e50] (r = 0,
# r below 1e-25 m or above 1e25 m, huge coordinates), coordinates large against the
# separation (|p_r|^2 + |p_t|^2 > 1e5 s: the expanded s and a = R^T p_r - R^T p_t lose
# more than ~1e-11 to cancellation), and receiver quaternions whose |q|^2 leaves
# [1e-16, 1e290].
#
# The same formulation, pair by pair with the same margins, is compiled in model_kernel.c
# (an optional extension; KERNEL / ARVA_MODEL_KERNEL choose): it runs by default when built,
# and leaves the pairs this path would hand to the general path undecided (zone -1).
#
# Fusing these passes with numexpr was measured and dropped (issue 20, 2026-12-01, in-process
# A/B, CPU time, numexpr 2.14.2 on one thread): its PyPI wheel runs scalar loops over
# strided operands while numpy's passes here are AVX-512, so on blocks held in L2 the fused
# G_x = a m - s b costs 1.10 ns/element vs 0.85 for numpy's three passes, and the batch was
# 30.3 ns/pair with the per-pose work in numexpr, 32.0 with the G chain, vs 30.2 as is.
# ---------------------------------------------------------------------------------------

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


class _FastTables:
    """Constants and the delta table of the fast path for one ModelParams."""

    def __init__(self, params: ModelParams) -> None:
        c = params.distance_scale
        self.lam = (200.0 * c) ** -3.0
        self.e_mid = (200.0 * params.r_outer) ** 6
        self.e_lo, self.e_hi = self.e_mid * (1.0 - _EDGE), self.e_mid * (1.0 + _EDGE)
        self.d_tol = _EDGE * (100.0 * max(params.r_outer, params.r_inner) + 1.0)  # cm
        self.v_inner = 200.0 * params.r_inner
        # Without noise |g| <= 2 (to rounding): d3 <= r_inner needs s <= this.
        self.s_inner = (params.r_inner * _CBRT2_MARGIN / c) ** 2
        k = np.arange(181)  # floor(degrees + 90.5) -> delta
        self.delta = np.clip(k - 90, -MAX_DELTA_DEG, MAX_DELTA_DEG).astype(np.int64)
        # The compiled kernel's constants, in the order model_kernel.fast_pairs takes them.
        self.kernel_consts = (self.e_lo, self.e_hi, self.d_tol, _DEG_TOL, _FOLD_TOL, _S_LO, _S_HI,
                              _CANCEL, _Q2_LO, _Q2_HI, self.s_inner, self.v_inner, _EDGE)

    @staticmethod
    def applies(params: ModelParams) -> bool:
        c = params.distance_scale
        return params.antennas == 3 and 1e-6 < c < 1e6 and params.r_inner < 1e6 and params.r_outer < 1e6


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
    bad = _NO_INDEX
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


class _FastTx:
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


def _compiled_kernel() -> bool:
    """Whether the fast path runs the compiled kernel (KERNEL; see its comment)."""
    if KERNEL == "numpy":
        return False
    if KERNEL == "auto":
        return model_kernel is not None
    if KERNEL == "compiled":
        if model_kernel is None:
            raise InputError("ARVA_MODEL_KERNEL=compiled: the extension emulator.receiver.model_kernel "
                             "is not built (reinstall with a C compiler: pip install -e .)")
        return True
    raise InputError(f"ARVA_MODEL_KERNEL: must be one of {', '.join(KERNELS)}, got {KERNEL!r}")


def _kernel_tx(tx_p, tx_m, lam: float) -> NDArray[np.float64]:
    """The compiled kernel's transmitter table (M, 10): p_t, lam m, 3 lam m, |p_t|^2."""
    return np.ascontiguousarray(np.hstack([tx_p, lam * tx_m.T, (3.0 * lam) * tx_m.T,
                                           np.sum(tx_p * tx_p, axis=1)[:, None]]))


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


@dataclass
class Epochs:
    """Channel-selected receiver output for N epochs: arrays of shape (N, channels).

    Empty slots are (id, d, delta) = (-1, -1, -1); ``tx_index`` is the column of the
    selected transmitter in the Measurement (-1 when empty), ``field`` its field.
    """

    ids: NDArray[np.int64]
    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    tx_index: NDArray[np.int64]
    field: NDArray[np.float64] | None = None


def select_channels(meas: Measurement, ids: ArrayLike, channels: int) -> Epochs:
    """Keep the ``channels`` nearest non-outer transmitters per epoch (BRIEF 3 step 6).

    Sorted by (d, id) ascending; ``ids`` (M,) must be sorted ascending so that a stable
    sort on d alone gives the (d, id) order.
    """
    ids = np.asarray(ids, dtype=np.int64)
    n, m = meas.d.shape
    key = np.where(meas.zone == ZONE_OUTER, np.iinfo(np.int64).max, meas.d)
    order = np.argsort(key, axis=1, kind="stable")[:, :channels]
    kept = np.take_along_axis(meas.zone, order, axis=1) != ZONE_OUTER
    out_ids = np.full((n, channels), -1, dtype=np.int64)
    out_d = np.full((n, channels), -1, dtype=np.int64)
    out_delta = np.full((n, channels), -1, dtype=np.int64)
    out_idx = np.full((n, channels), -1, dtype=np.int64)
    width = order.shape[1]
    out_ids[:, :width] = np.where(kept, ids[order], -1)
    out_d[:, :width] = np.where(kept, np.take_along_axis(meas.d, order, axis=1), -1)
    out_delta[:, :width] = np.where(kept, np.take_along_axis(meas.delta, order, axis=1), -1)
    out_idx[:, :width] = np.where(kept, order, -1)
    fld = None
    if meas.field is not None:
        fld = np.zeros((n, channels, 3))
        fld[:, :width] = np.take_along_axis(meas.field, order[..., None], axis=1)
        fld[out_idx < 0] = 0.0
    return Epochs(out_ids, out_d, out_delta, out_idx, fld)


def measure_one(
    rx_position: ArrayLike,
    rx_orientation: ArrayLike,
    tx_position: ArrayLike,
    tx_orientation: ArrayLike = (1.0, 0.0, 0.0, 0.0),
    params: ModelParams = ModelParams(),
) -> tuple[int, int]:
    """(d [cm], delta [deg]) of one receiver pose and one transmitter, ideal receiver.

    A thin wrapper over :func:`measure`, so both share one implementation.
    """
    meas = measure(
        np.asarray(rx_position, dtype=np.float64)[None],
        np.asarray(rx_orientation, dtype=np.float64)[None],
        np.asarray(tx_position, dtype=np.float64)[None],
        np.asarray(tx_orientation, dtype=np.float64)[None],
        params,
    )
    return int(meas.d[0, 0]), int(meas.delta[0, 0])
