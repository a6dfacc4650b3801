"""How error in the logged receiver pose moves each row's predicted distance (errors in variables).

The likelihood predicts log d from the logged poses through

    a_xy = log r - log |g_xy| / 3   (mid zone)      a_3 = log r - log |g| / 3   (inner zone)

(r in metres, g the receiver-frame field direction, BRIEF 3). The logged receiver
position is the true one plus GPS error e (world frame, metres; sigma_h on x and y,
sigma_v = ratio * sigma_h on z), and the logged attitude is the true one turned by a
small body-frame rotation phi (radians, sigma_a on each axis). The transmitter pose is
taken as exact (it is buried and static). So the true a is a(logged pose - error): a
random variable for each row.

The errors are classical (logged = true + error, the error independent of the truth), so
the logged poses are spread wider than the true ones: the rule below is applied around
each row's posterior mean pose, not the logged one (:func:`posterior_positions`: Tweedie
shift of the horizontal position, shrinkage of the height; :func:`posterior_attitudes`:
shrinkage of pitch and roll), and draws the error around it as if it were independent of
that centre (the posterior spread left, k sigma^2, is taken as sigma^2 for the attitude).

This module replaces that distribution by a Gaussian with the same mean and variance
(moment matching), from a 3-point Gauss-Hermite rule along each of the six error axes
(nodes at +-sqrt(3) sigma_0, weights 1/6, 2/3, 1/6):

    mean shift  = sum_j sigma_j^2 M_j,   variance = sum_j sigma_j^2 V_j

with M_j = (D+ + D-) / (6 sigma_0j^2), V_j = [(D+^2 + D-^2)/6 - ((D+ + D-)/6)^2] / sigma_0j^2,
D+- = a(pose +- sqrt(3) sigma_0j along axis j) - a(pose). Both are exact for a that is
quadratic along each axis at sigma = sigma_0 and scale as sigma^2 around it; the fit
evaluates them at a pilot sigma_0 and again at its estimate (:func:`pose_moments`).
Cross terms between axes are left out (the six errors are independent; only the mixed
second derivatives are neglected). The axis sums are kept per group (horizontal,
vertical, attitude) so the likelihood can scale each by its own sigma.

Far from the transmitter the variance is ~ (sigma_h^2 + sigma_v^2 ...) / r^2 and the shift
tiny; within a few sigma of it the Gaussian is a rough stand-in for a skewed distribution,
and :data:`MAX_SD` says which rows are left out of the fit for that reason (see
docs/calibration.md section 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from emulator.frames.rotation import (
    quaternion_conjugates,
    quaternion_products,
    rotation_components,
    unit_quaternion_components,
    x_axis_components,
)

from .special import Z_BLEND, Z_KINK, Z_SPAN, ball_disk_cdf, normal_pieces

SQRT3 = math.sqrt(3.0)
#: Rows whose predicted log-distance spread from the pose error (at the linearisation
#: sigmas) exceeds this are not used: the moment-matched Gaussian is poor there and such
#: rows carry almost no information on kappa_eq or r_en.
MAX_SD = 0.15
#: The piecewise rule of :func:`signal_error_cdf` and :func:`signal_error_bin`: pieces
#: of at most this many s.d. of Z, this many Gauss-Legendre nodes each (the exact-pose
#: rule of ``special``: 2 s.d., 6 nodes). On 4,000 random near-kink rows (s3 0.01-0.3,
#: log gamma -2 to 3, t within 7 s.d. of a kink) against 12 nodes per 0.125 s.d. the
#: CDF was within 2.4e-7 (2 s.d. / 6 nodes: 1.8e-7; 3 / 6: 2.3e-6; 4 / 7: 2.9e-6) and a
#: narrow bin within 9.1e-8, both at the level of the ball rule's own error (G to
#: 3e-7); on the 10,000-row subsample of the 1e5-row pose-error bench campaign (seed 0)
#: at its estimate log P per row within 3.1e-5 of that reference (2 / 6: 3.6e-5), for
#: 12 % less CPU per evaluation (10.2 -> 8.9 ms; tests/perf/fit_pieces.py, 2026-12-05,
#: 2-core EPYC at load 7-10; 13-15 % in two other runs).
SIGNAL_PIECE = (4.0, 8)
#: The rule of the fit's linearising passes (all errors-in-variables passes but the
#: third, :func:`estimate.fit_once`): 2 s.d., 6 nodes, as before SIGNAL_PIECE. Their
#: estimates choose the sigmas of the next pass's moments, and so which near rows are
#: left out (:data:`MAX_SD`) and, above 10,000 rows, the subsample drawn from the rest: a
#: change of ~1e-5 in their log P moved the final estimates of 1e5-row campaigns by up
#: to 0.4 standard errors (kappa_eq, r_en; attitude_sigma by up to 1.8) through the rows
#: alone, so those passes keep the rule they had. (A fit whose sigmas settle before the
#: third pass ends on such a pass: above 10,000 rows its all-row stage then switches to
#: SIGNAL_PIECE; on smaller tables, or with time_offset or r_outer free, the estimate keeps
#: this rule, within 2.4e-7 per row of the same reference as SIGNAL_PIECE.)
LINEARISING_PIECE = (2.0, 6)


@dataclass
class PoseMoments:
    """Per-row mean-shift and variance coefficients of a_xy and a_3, per error group
    (h: horizontal GPS per m^2, v: vertical GPS per m^2, a: attitude per rad^2)."""

    m_xy: NDArray[np.float64]  # (3, N): h, v, a
    v_xy: NDArray[np.float64]  # (3, N)
    m_3: NDArray[np.float64]
    v_3: NDArray[np.float64]
    sigma0: tuple[float, float, float]  # the sigmas the rule was evaluated at (m, m, rad)
    dz_xy: NDArray[np.float64]  # d a_xy / d (receiver height), 1/m (for the height offset)
    dz_3: NDArray[np.float64]
    #: the likelihood's piecewise rule over this pose error, (longest piece in s.d. of Z,
    #: Gauss-Legendre nodes per piece) (:func:`signal_error_cdf`; :data:`SIGNAL_PIECE`, or
    #: the fit's linearising passes' :data:`LINEARISING_PIECE`)
    piece: tuple[float, int] = SIGNAL_PIECE

    def take(self, idx) -> "PoseMoments":
        return PoseMoments(
            self.m_xy[:, idx], self.v_xy[:, idx], self.m_3[:, idx], self.v_3[:, idx], self.sigma0,
            self.dz_xy[idx], self.dz_3[idx], self.piece,
        )  # fmt: skip

    def spread(self, s: NDArray[np.float64] | tuple) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """(shift_xy, var_xy, shift_3, var_3) for sigmas s = (h, v, a) (squared inside)."""
        w = np.asarray(s, dtype=np.float64) ** 2
        return w @ self.m_xy, np.maximum(w @ self.v_xy, 0.0), w @ self.m_3, np.maximum(w @ self.v_3, 0.0)


def _a(diff, m, rr_t_rows):
    """a_xy, a_3 for rx - tx offsets ``diff`` (3, N), transmitter axes m (3, N) and the
    receiver rotations (3, 3, N) (g = R^T u_w)."""
    r = np.sqrt(np.einsum("in,in->n", diff, diff))
    n = diff / np.where(r > 0, r, 1.0)
    uw = 3.0 * np.einsum("in,in->n", m, n) * n - m
    g = np.einsum("ijn,in->jn", rr_t_rows, uw)
    return _a_of(r, g)


def _a_of(r, g):
    with np.errstate(divide="ignore"):
        log_r = np.log(r)
        gxy = np.hypot(g[0], g[1])
        return log_r - np.log(gxy) / 3.0, log_r - 0.5 * np.log(gxy * gxy + g[2] * g[2]) / 3.0


def _rotate(g, axis: int, angle: float):
    """g (3, N) turned by ``angle`` about body axis ``axis``: the true g when the logged
    attitude is off by that rotation (g_true = R(phi) g_logged to first order and beyond)."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out = g.copy()
    out[i] = c * g[i] - s * g[j]
    out[j] = s * g[i] + c * g[j]
    return out


@dataclass
class Posterior:
    """Where the receiver was, given its logged position: logged + shift (n, 3), and the
    vertical error's posterior s.d. as a fraction of sigma_v."""

    pos: NDArray[np.float64]
    v_factor: float


def posterior_positions(rx_pos, tx_pos, sigma_h: float, sigma_v: float) -> Posterior:
    """E[true position | logged position] for logged = true + e (classical error).

    Horizontal (Tweedie's formula): E[x | x_log] = x_log + sigma_h^2 grad log p(x_log),
    p the density of the logged positions, estimated as radial about the transmitter:
    p ~ n(rho) / rho with n a Gaussian-smoothed histogram of the logged horizontal
    distances rho (bandwidth max(sigma_h, 1 m)); the shift is capped at sigma_h. A radial
    walk (n flat) gives the shift -sigma_h^2 / rho towards the transmitter: without it the
    fit sees every distance as too long by sigma_h^2 / (2 rho^2) on average, and kappa_eq
    came out 1.8 % low at 1 m GPS error.
    Vertical (empirical Bayes, Gaussian prior on the height): the true heights vary by
    tau^2 = max(var(z_log) - sigma_v^2, 0), so E[z | z_log] = m + k (z_log - m) with
    k = tau^2 / (tau^2 + sigma_v^2), and the error left has s.d. sqrt(k) sigma_v.
    """
    pos = np.array(rx_pos, dtype=np.float64)
    rel = pos - np.asarray(tx_pos, dtype=np.float64)
    if sigma_h > 0:
        rho = np.hypot(rel[:, 0], rel[:, 1])
        bw = max(sigma_h, 1.0)
        width = bw / 4.0
        edges_n = int(np.ceil((rho.max() + 4 * bw) / width)) + 1
        hist = np.bincount(np.minimum((rho / width).astype(np.int64), edges_n - 1), minlength=edges_n).astype(float)
        kx = np.arange(-16, 17) * width
        kern = np.exp(-0.5 * (kx / bw) ** 2)
        padded = np.concatenate([hist[16:0:-1], hist])  # reflect at rho = 0
        dens = np.convolve(padded, kern, mode="same")[16:] + 1e-9
        centres = (np.arange(edges_n) + 0.5) * width
        dlog = np.gradient(np.log(dens), centres)
        slope = np.interp(rho, centres, dlog) - 1.0 / np.maximum(rho, 1e-9)
        step = np.clip(sigma_h * sigma_h * slope, -sigma_h, sigma_h)
        unit = rel[:, :2] / np.maximum(rho, 1e-9)[:, None]
        pos[:, :2] += step[:, None] * unit
    k = 1.0
    if sigma_v > 0:
        z = pos[:, 2]
        m = float(np.mean(z))
        tau2 = max(float(np.var(z)) - sigma_v * sigma_v, 0.0)
        k = tau2 / (tau2 + sigma_v * sigma_v)
        pos[:, 2] = m + k * (z - m)
    return Posterior(pos, math.sqrt(k))


def posterior_attitudes(rx_quat, sigma_a: float) -> NDArray[np.float64]:
    """E[true tilt | logged tilt] for logged = true turned by a small body-frame error
    (classical error, sigma_a rad per axis): the logged quaternions (n, 4) ``[w, x, y, z]``
    with their pitch and roll (intrinsic z-y-x angles: the tilt, i.e. where the world's
    up points in the body frame) shrunk towards their campaign means, heading unchanged.

    Empirical Bayes with a Gaussian prior per angle, as the heights in
    :func:`posterior_positions`: the true angles vary by tau^2 = max(var(logged) -
    sigma_a^2, 0), so E[theta | theta_log] = m + k (theta_log - m), k = tau^2 / (tau^2 +
    sigma_a^2) (the error on pitch and roll is taken as sigma_a, exact for a level
    receiver). Why: the rule of :func:`pose_moments` draws the true attitude around the
    logged one (a Berkson error), but the logged tilt is the true one plus the error, so
    it is spread wider than the truth; |g_xy| is largest for a level receiver in a
    horizontal field, so a tilt too large on average makes a_xy too large on average and
    kappa_eq too small. Shrinking the tilt first is Tweedie's formula for a Gaussian
    tilt distribution (the rule then spreads the attitude around the posterior mean;
    the error left, k sigma_a^2 on the tilt, is taken as sigma_a^2: k > 0.98 for holds
    of 20 deg at 2 deg error). Measured on 50 seeded 4-hour campaigns (1 m / 1.5 m GPS,
    2 deg attitude, sigmas given, kappa_eq alone free): +0.039 +- 0.017 % on kappa_eq,
    most of the attitude error's part of its low bias (docs/calibration.md section 2).
    Angles are not unwrapped: a roll spread across +-180 deg has a huge variance and
    k ~ 1 (no shrinkage). The result is normalised (the input need not be)."""
    q = np.array(rx_quat, dtype=np.float64)
    if sigma_a <= 0.0 or q.shape[0] < 2:
        return q
    q = unit_quaternion_components(q, "rx_q").T  # logged quaternions need not be unit
    w, x, y, z = q.T
    pitch = -np.arcsin(np.clip(2.0 * (x * z - w * y), -1.0, 1.0))
    roll = np.arctan2(2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    new = []
    for ang in (pitch, roll):
        var = float(np.var(ang))
        k = max(var - sigma_a * sigma_a, 0.0) / var if var > 0.0 else 1.0
        m = float(np.mean(ang))
        new.append(m + k * (ang - m))

    def tilt(p, r):  # Ry(p) Rx(r) as quaternions (n, 4)
        cp, sp, cr, sr = np.cos(0.5 * p), np.sin(0.5 * p), np.cos(0.5 * r), np.sin(0.5 * r)
        return np.stack([cp * cr, cp * sr, sp * cr, -sp * sr], axis=-1)

    # R' = Rz(yaw) Ry(p') Rx(r') = R (Ry(p) Rx(r))^T Ry(p') Rx(r')
    turn = quaternion_products(quaternion_conjugates(tilt(pitch, roll)), tilt(*new))
    return quaternion_products(q, turn)


def pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0: tuple[float, float, float]) -> PoseMoments:
    """The coefficients of :class:`PoseMoments` for each row, at sigmas ``sigma0``
    (horizontal m, vertical m, attitude rad; each > 0). Rows at the transmitter get
    zeros (they are dropped by the fit anyway); non-finite values become 0 shift and a
    huge variance, so those rows drop out."""
    rr = rotation_components(unit_quaternion_components(rx_quat, "rx_q"))  # (3, 3, N)
    m = x_axis_components(unit_quaternion_components(tx_quat, "tx_q"))
    diff = (np.asarray(rx_pos, float) - np.asarray(tx_pos, float)).T
    n = diff.shape[1]
    a0 = _a(diff, m, rr)
    r = np.sqrt(np.einsum("in,in->n", diff, diff))
    uw_n = diff / np.where(r > 0, r, 1.0)
    g0 = np.einsum("ijn,in->jn", rr, 3.0 * np.einsum("in,in->n", m, uw_n) * uw_n - m)
    out = [np.zeros((3, n)) for _ in range(4)]  # m_xy, v_xy, m_3, v_3
    dz = [np.zeros(n), np.zeros(n)]

    def accumulate(group, plus, minus, s0):
        if group == 1:  # the vertical axis: also the slope, for the height offset
            for k in range(2):
                dz[k] = (plus[k] - minus[k]) / (2.0 * SQRT3 * s0)
        for k in range(2):
            dp, dm = plus[k] - a0[k], minus[k] - a0[k]
            mean = (dp + dm) / 6.0
            var = (dp * dp + dm * dm) / 6.0 - mean * mean
            out[2 * k][group] += mean / (s0 * s0)
            out[2 * k + 1][group] += var / (s0 * s0)

    sh, sv, sa = sigma0
    for axis, group, s0 in ((0, 0, sh), (1, 0, sh), (2, 1, sv)):
        step = np.zeros((3, 1))
        step[axis] = SQRT3 * s0
        # logged = true + e, so the true offset is diff - e: the rule is symmetric in e.
        accumulate(group, _a(diff + step, m, rr), _a(diff - step, m, rr), s0)
    for axis in range(3):
        accumulate(2, _a_of(r, _rotate(g0, axis, SQRT3 * sa)), _a_of(r, _rotate(g0, axis, -SQRT3 * sa)), sa)
    m_xy, v_xy, m_3, v_3 = out
    bad = ~(np.all(np.isfinite(m_xy), axis=0) & np.all(np.isfinite(v_xy), axis=0))
    bad |= ~(np.all(np.isfinite(m_3), axis=0) & np.all(np.isfinite(v_3), axis=0))
    if bad.any():
        for arr, fill in ((m_xy, 0.0), (v_xy, 1e12), (m_3, 0.0), (v_3, 1e12)):
            arr[:, bad] = fill
    dz_xy, dz_3 = (np.where(np.isfinite(v) & ~bad, v, 0.0) for v in dz)
    return PoseMoments(m_xy, v_xy, m_3, v_3, (float(sh), float(sv), float(sa)), dz_xy, dz_3)


# -- the far rows: pose error moves the signal, not the EMI ---------------------------
#
# In the exact (L) rule of the likelihood |h_xy| = |c_xy + n|: the EMI ball n has a fixed
# field radius b (set by r_en), the signal c_xy = g_xy / (4 pi r^3) comes from the true
# pose. With a_xy = log r - log |g_xy| / 3 off by Delta (the pose error's effect, mean m,
# s.d. sigma), |c_xy| is e^{-3 Delta} times the modelled one and the noise stays put:
#
#     P(log dxy > y) = E[G(t(y); gamma e^{-3 Delta})],  G(t; gamma) = P(|gamma e_x + n| < t)
#
# (t, gamma in units of b). Treating Delta as a log-normal factor on d after the EMI
# (the relative ``pose_sigma`` model) would scale the noise with the signal instead: then
# a row whose true distance is longer than logged looks exactly as noisy as one that is
# shorter, the spread the pose error adds is mistaken for less EMI, and r_en came out
# +0.7 % high (4-hour campaigns, 1 m GPS error; measured, docs/calibration.md section 2).

_GH3_X = np.array([-SQRT3, 0.0, SQRT3])
_GH3_W = np.array([1.0, 4.0, 1.0]) / 6.0


def signal_error_cdf(log_t, log_gamma, s3, piece: tuple[float, int] = SIGNAL_PIECE) -> NDArray[np.float64]:
    """E[G(t; gamma e^{-s3 Z})], Z standard normal: P(log dxy > y) for threshold
    t = e^{log_t} (noise radii) when the pose error scales the signal (all one per row;
    s3 = 3 sigma > 0; ``log_gamma`` includes -3 m, the pose error's mean effect).

    As a function of Z, G = 0 below za (gamma' > t + 1), has its other kink at zb
    (gamma' = |t - 1|) and is 1 above it when t > 1 (for t < 1 it tends smoothly to
    G(t; 0)). Rows with both kinks at least ``Z_KINK`` s.d. away take the 3-point
    Gauss-Hermite rule; the others are integrated only where G is neither 0 nor 1, in
    pieces split at the kinks (:func:`special.normal_pieces`; ``piece``: their longest
    length in s.d. and their nodes), blended into the 3-point value over ``Z_BLEND`` s.d.
    (the scheme of :func:`special.smoothed_ball_disk_cdf`, which puts the same error on the
    threshold)."""
    return _signal_rule(log_t, log_gamma, s3, False, piece)


def signal_error_bin(log_t_mid, delta, log_gamma, s3, piece: tuple[float, int] = SIGNAL_PIECE) -> NDArray[np.float64]:
    """E[G(t e^{delta/2}; gamma') - G(t e^{-delta/2}; gamma')], gamma' = gamma e^{-s3 Z}:
    the probability of a bin of width delta in log t (all one per row), for bins with
    delta <= :data:`BIN_W_MAX` s3 min(1, gamma). The two edges share gamma' at every
    node, so instead of two CDFs the density is taken once, at the bin's middle:
    P = delta E[t dG/dt (t; gamma')], the midpoint rule in log t. Its relative error is
    ~ (w z)^2 / 24, w = delta / scale and z the bin's distance from C's median in the same
    scale, where C = E[G] varies on a scale of s3 in log t (the smoothing over Z) when
    gamma >= 1 and of ~ s3 gamma near t = 1 when gamma < 1 (the band |gamma' - 1| < t <
    gamma' + 1 is that narrow): hence the min(1, gamma). Measured against fine quadrature
    (tests/bench/fit/test_fit_pose_error.py): within 2e-4 of P; on the 1e5-row pose-error bench
    (1 cm bins, w ~ 0.01) within 8e-5 of the two-CDF value on every row. Same rules
    (3-point Gauss-Hermite, pieces between the kinks, blend) as :func:`signal_error_cdf`;
    t dG/dt is 0 where G is 0 or 1, so there is no tail term. ``piece``: as for
    :func:`signal_error_cdf`."""
    delta = np.asarray(delta, dtype=np.float64)
    return np.maximum(delta * _signal_rule(log_t_mid, log_gamma, s3, True, piece), 0.0)


#: :func:`signal_error_bin` is used for bins narrower than this many s3 min(1, gamma)
#: (the likelihood's choice is frozen per optimisation pass, as Regimes.narrow).
BIN_W_MAX = 0.015


def _signal_rule(log_t, log_gamma, s3, density: bool, piece: tuple[float, int]) -> NDArray[np.float64]:
    """E[G] (or with ``density``: E[t dG/dt]) at t = e^{log_t}, gamma' = gamma e^{-s3 Z}."""
    log_t = np.asarray(log_t, dtype=np.float64)
    log_gamma = np.broadcast_to(np.asarray(log_gamma, dtype=np.float64), log_t.shape)
    s3 = np.broadcast_to(np.asarray(s3, dtype=np.float64), log_t.shape)
    # G = 1 once t exceeds the largest gamma' + 1 reached within Z_SPAN s.d.
    top = np.logaddexp(np.minimum(log_gamma + Z_SPAN * s3, 700.0), 0.0) + 1.0
    log_t = np.clip(np.where(np.isnan(log_t), -np.inf, log_t), -745.0, top)
    t = np.exp(log_t)
    with np.errstate(divide="ignore", invalid="ignore"):
        za = (log_gamma - np.log1p(t)) / s3
        zb = (log_gamma - np.log(np.abs(t - 1.0))) / s3
    za = np.where(np.isnan(za), -np.inf, za)
    zb = np.where(np.isnan(zb), -np.inf, zb)
    zmin = np.minimum(np.abs(za), np.abs(zb))
    out = np.empty(log_t.shape)
    far = np.flatnonzero(zmin >= Z_KINK)
    if far.size:
        with np.errstate(over="ignore"):
            gam = np.exp(np.minimum(log_gamma[far, None] - s3[far, None] * _GH3_X, 700.0))
        out[far] = _g(np.broadcast_to(t[far, None], gam.shape), gam, density) @ _GH3_W
    near = np.flatnonzero(zmin < Z_KINK + Z_BLEND)
    if not near.size:
        return out
    acc = _pieces(t[near], log_gamma[near], s3[near], za[near], zb[near], density, piece)
    x = np.clip((zmin[near] - Z_KINK) / Z_BLEND, 0.0, 1.0)
    w = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
    gh = np.where(w > 0.0, out[near], 0.0)
    out[near] = w * gh + (1.0 - w) * acc
    if not density:
        out[near] = np.clip(out[near], 0.0, 1.0)
    return out


def _g(t, gamma, density: bool):
    """G(t; gamma), or t dG/dt (:func:`special.ball_disk_cdf`)."""
    return ball_disk_cdf(t, gamma, density=density)


def _pieces(t, lg, s3, za, zb, density: bool, piece: tuple[float, int]) -> NDArray[np.float64]:
    """The piecewise integral of :func:`_signal_rule` (one value per row)."""
    above = t > 1.0  # G = 1 above zb
    lo = np.clip(za, -Z_SPAN, Z_SPAN)
    hi = np.where(above, np.maximum(np.clip(zb, -Z_SPAN, Z_SPAN), lo), Z_SPAN)
    mid = np.clip(zb, lo, hi)
    row, z, wz = normal_pieces(lo, mid, hi, *piece)
    with np.errstate(over="ignore"):
        gam = np.exp(np.minimum(lg[row][:, None] - s3[row][:, None] * z, 700.0))
    gz = _g(np.broadcast_to(t[row][:, None], gam.shape), gam, density)
    acc = np.bincount(row, weights=np.einsum("ij,ij->i", wz, gz), minlength=t.shape[0])
    if density:  # t dG/dt = 0 where G = 1
        return acc
    return acc + np.where(above, ndtr(-np.maximum(zb, -40.0)), 0.0)
