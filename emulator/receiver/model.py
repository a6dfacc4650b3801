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

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import InputError, PoseError

from emulator.frames.rotation import rotation_components, unit_quaternion_components, x_axis_components

ZONE_INNER, ZONE_MID, ZONE_OUTER = 0, 1, 2
ZONE_NAMES = ("inner", "mid", "outer")
#: Receiver classes the model knows: antennas used for the distance (2: horizontal pair).
ANTENNAS = (2, 3)
MAX_DELTA_DEG = 89
#: Largest magnitude a $PARVH component can carry; fields beyond it (r below ~1e-103 m)
#: saturate here rather than print ``inf``.
FIELD_SATURATION = float(np.finfo(np.float64).max)
#: Transmitters are processed in chunks of this many pairs so temporaries stay in cache.
CHUNK_PAIRS = 1 << 15
_HUGE = 2.0**1020  # ~1.1e307


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
    if not np.all(np.isfinite(p)):
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
) -> Measurement:
    """Evaluate N receiver poses against M transmitters.

    ``rx_position`` (N, 3) and ``rx_orientation`` (N, 4); ``tx_position`` (M, 3) or
    (N, M, 3) and ``tx_orientation`` (M, 4) or (N, M, 4) for moving transmitters.
    Quaternions need not be normalised. ``noise``, when given, is (N, M, 3) points of
    the unit ball in the world frame (see :mod:`emulator.receiver.noise`); they are scaled by
    ``params.w_en`` and mapped by Q R_r^T (BRIEF 3.2). ``noise=None`` is the ideal
    receiver and costs nothing extra. ``params.antennas`` selects the receiver class
    (3: BRIEF 3; 2: the horizontal field in every zone, see the module docstring).
    """
    rx_p = as_positions(rx_position, "receiver.position")
    tx_p = as_positions(tx_position, "transmitter.position")
    # Component-major (see emulator.frames.rotation): receiver matrices (3, 3, N), transmitter
    # dipole axes (3, M) or (3, N, M).
    rx_r = rotation_components(unit_quaternion_components(rx_orientation, "receiver.orientation"))
    tx_m = x_axis_components(unit_quaternion_components(tx_orientation, "transmitter.orientation"))
    n = rx_p.shape[0]
    m = tx_p.shape[-2]
    moving_tx = tx_p.ndim == 3 or tx_m.ndim == 3
    if moving_tx:
        tx_p = np.broadcast_to(tx_p, (n, m, 3))
        tx_m = np.broadcast_to(tx_m if tx_m.ndim == 3 else tx_m[:, None, :], (3, n, m))
    d = np.empty((n, m), dtype=np.int64)
    delta = np.empty((n, m), dtype=np.int64)
    zone = np.empty((n, m), dtype=np.int8)
    fld = np.empty((n, m, 3)) if want_field else None
    rows = max(1, CHUNK_PAIRS // max(m, 1))
    for lo in range(0, n, rows):
        sl = slice(lo, min(n, lo + rows))
        _measure_chunk(
            rx_p[sl],
            rx_r[:, :, sl],
            tx_p[sl] if moving_tx else tx_p,
            tx_m[:, sl] if moving_tx else tx_m,
            params,
            None if noise is None else noise[sl],
            d[sl],
            delta[sl],
            zone[sl],
            None if fld is None else fld[sl],
        )
    return Measurement(d, delta, zone, fld)


def _measure_chunk(rx_p, rx_r, tx_p, tx_m, params, noise, d_out, delta_out, zone_out, field_out):
    # Only the dipole axis m = R_t e_x (first column of R_t) matters: with n the world
    # unit vector from transmitter to receiver and x = m.n (the transmitter-frame x of
    # p/r), A(p)/r^2 = 3 x (p/r) - e_x in the transmitter frame, i.e. u_w = 3 x n - m in
    # the world frame. Same field as eq. 1 rotated by R_t, in 3x fewer operations.
    if tx_m.ndim == 2:  # static transmitters: (M,) broadcast against (n, M)
        mx, my, mz = tx_m[:, None, :]
        tx = tx_p[None]
    else:
        mx, my, mz = tx_m
        tx = tx_p
    rr = lambda i, j: rx_r[i, j, :, None]  # noqa: E731

    # Coordinates beyond ~1e307 could overflow the difference; a chunk holding any is
    # scaled by an exact power of two first, and distances are scaled back (to inf:
    # outer). Scaling normal floats by 1/4 is exact, so results do not change.
    big = max(np.max(np.abs(rx_p), initial=0.0), np.max(np.abs(tx), initial=0.0)) > _HUGE
    f = 0.25 if big else 1.0
    dx = rx_p[:, None, 0] * f - tx[..., 0] * f
    dy = rx_p[:, None, 1] * f - tx[..., 1] * f
    dz = rx_p[:, None, 2] * f - tx[..., 2] * f
    r_scaled = norm3(dx, dy, dz)
    at_tx = r_scaled == 0.0
    r_dir = np.where(at_tx, 1.0, r_scaled)
    dx /= r_dir
    dy /= r_dir
    dz /= r_dir
    with np.errstate(over="ignore"):
        r_safe = r_dir / f  # true distance; inf only for pairs ~1e308 m apart
    x3 = 3.0 * (mx * dx + my * dy + mz * dz)
    uw0 = x3 * dx - mx
    uw1 = x3 * dy - my
    uw2 = x3 * dz - mz
    # Receiver frame: g = R_r^T u_w (h = s / (4 pi r^3) g).
    g0 = rr(0, 0) * uw0 + rr(1, 0) * uw1 + rr(2, 0) * uw2
    g1 = rr(0, 1) * uw0 + rr(1, 1) * uw1 + rr(2, 1) * uw2
    g2 = rr(0, 2) * uw0 + rr(1, 2) * uw1 + rr(2, 2) * uw2

    with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
        if noise is None:
            dist_scale = r_safe * params.distance_scale
            field_scale = None
            if field_out is not None:
                field_scale = (params.moment / (4.0 * math.pi)) / r_safe**3
        else:
            g0, g1, g2, dist_scale, field_scale = _add_noise(
                g0, g1, g2, r_safe, rx_r, noise, params, field_out is not None
            )
        gxy = norm2(g0, g1)
        dxy = dist_scale / np.cbrt(gxy)  # gxy == 0: inf
        if params.antennas == 3:
            d3 = dist_scale / np.cbrt(norm3(g0, g1, g2))  # |g| == 0 (noise cancelling): inf
            inner = at_tx | (d3 <= params.r_inner)
            dist = np.where(inner, d3, dxy)
        else:  # 2 antennas: the horizontal field in every zone
            inner = at_tx | (dxy <= params.r_inner)
            dist = dxy.copy()
        outer = ~inner & ~((gxy > 0.0) & (dxy <= params.r_outer))
        dist[at_tx] = 0.0
        dist *= 100.0
        d_out[...] = round_half_away(dist)
        angle = np.degrees(np.arctan(g1 / np.where(g0 == 0.0, 1.0, g0)))
        np.copyto(angle, np.copysign(90.0, g1), where=g0 == 0.0)  # atan(+-inf), sign of h_y
        delta = np.clip(round_half_away(angle), -MAX_DELTA_DEG, MAX_DELTA_DEG)
        delta[inner] = 0.0
        delta_out[...] = delta

    np.putmask(d_out, outer, -1)
    np.putmask(delta_out, outer, -1)
    zone_out[...] = outer  # ZONE_OUTER = 2 = outer + not inner; ZONE_MID = 1; ZONE_INNER = 0
    zone_out += ~inner
    if field_out is not None:
        for i, g in enumerate((g0, g1, g2)):
            with np.errstate(over="ignore", invalid="ignore"):
                h = np.where(g == 0.0, 0.0, g * field_scale)
            h[at_tx] = 0.0
            field_out[..., i] = np.clip(h, -FIELD_SATURATION, FIELD_SATURATION)
        if params.antennas == 2:
            field_out[..., 2] = 0.0  # no z antenna: a 2-antenna unit cannot report h_z


def _add_noise(g0, g1, g2, r, rx_r, noise, params, want_scale):
    """Add EMI (BRIEF 3.2) in the scaled form described in the module docstring."""
    q = params.q
    # v = Q R_r^T w_hat: receiver-frame noise, per unit of w_en.
    wx, wy, wz = noise[..., 0], noise[..., 1], noise[..., 2]
    rr = lambda i, j: rx_r[i, j, :, None]  # noqa: E731
    v0 = q[0] * (rr(0, 0) * wx + rr(1, 0) * wy + rr(2, 0) * wz)
    v1 = q[1] * (rr(0, 1) * wx + rr(1, 1) * wy + rr(2, 1) * wz)
    v2 = q[2] * (rr(0, 2) * wx + rr(1, 2) * wy + rr(2, 2) * wz)
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
