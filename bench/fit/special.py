"""The two distributions the likelihood is built from (derivations in docs/calibration.md).

``E`` is the projection of a point uniform in the unit 3-ball onto a line: density
(3/4)(1 - x^2) on [-1, 1]. ``n`` is its projection onto a plane: density
(3 / 2 pi) sqrt(1 - |n|^2) on the unit disk.

* :func:`epan_gauss_cdf` — P(e E + s Z <= u), Z standard normal, in closed form: the
  small-noise receiver (EMI linearised) with the Gaussian pose error.
* :func:`ball_disk_cdf` — P(|gamma e_x + n| <= t): the exact distribution of the
  receiver's |(h_x, h_y)| under ball noise, by an 8-node Gauss-Legendre rule after a
  substitution that removes the square-root end-point behaviour (error < 3e-7, see the
  accuracy table in docs/calibration.md).
* :func:`smoothed_ball_disk_cdf` / :func:`smoothed_ball_disk_bin` — G seen through the
  log-normal pose error, and the probability of a bin narrow against it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
#: Below this e/s the series in (e/s)^2 is used (its truncation error is < 1e-11).
SERIES_BELOW = 0.05


def _phi(z):
    return _INV_SQRT_2PI * np.exp(-0.5 * z * z)


def epan_cdf(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """P(E <= x) = (2 + 3x - x^3) / 4 on [-1, 1]."""
    x = np.clip(x, -1.0, 1.0)
    return (2.0 + 3.0 * x - x * x * x) * 0.25


def epan_gauss_cdf(u, e, s, density: bool = False):
    """P(e E + s Z <= u) for arrays u, e >= 0 and s > 0 (a scalar, or one per element;
    a scalar s = 0: no Z). With ``density`` (s > 0): (P, f, f'), f and f' as
    :func:`epan_gauss_density` gives them, from the same partial moments (the same bits
    as the two calls, with the moments computed once).

    With z1,2 = (u -+ e)/s and x = (u - s Z)/e, P = Phi(z1) + E[F_E(x); z1 < Z < z2] where
    F_E(x) = (2 + 3x - x^3)/4 is a cubic in Z, so the second term is a combination of the
    partial moments M_k = E[Z^k; z1 < Z < z2] (closed form in Phi and phi). When e/s is
    small the cancellation in that combination grows, and the series
    Phi(u/s) - (h^2/10) zc phi(zc) + (h^4/280)(3 zc - zc^3) phi(zc), h = e/s, is used instead.
    """
    u = np.asarray(u, dtype=np.float64)
    e = np.broadcast_to(np.asarray(e, dtype=np.float64), u.shape)
    if np.ndim(s) == 0 and not density:
        s = float(s)
        if s <= 0.0:
            with np.errstate(divide="ignore", invalid="ignore"):
                x = u / e
            return epan_cdf(np.where(e > 0, x, np.sign(u)))
    return _epan_gauss(u, e, s, True, density)


def _epan_gauss(u, e, s, cdf: bool, density: bool):
    """The body of :func:`epan_gauss_cdf` (``cdf``) and :func:`epan_gauss_density`
    (``density``) for s > 0: a list of P and/or (f, f')."""
    ss = float(s) if np.ndim(s) == 0 else np.broadcast_to(np.asarray(s, dtype=np.float64), u.shape)
    if cdf:
        out = np.where(u > 0, 1.0, 0.0)  # the values at u = -inf, +inf
    if density:
        f = np.zeros(u.shape)
        df = np.zeros(u.shape)
    finite = np.isfinite(u)
    h = e / ss
    series = finite & (h < SERIES_BELOW)
    if series.any():
        sc = ss if np.ndim(ss) == 0 else ss[series]
        zc = u[series] / sc
        hh = h[series] ** 2
        p = _phi(zc)
        if cdf:
            out[series] = ndtr(zc) - 0.1 * hh * zc * p + (hh * hh / 280.0) * (3.0 * zc - zc**3) * p
        if density:
            z2 = zc * zc
            c2, c4 = 0.1 * hh, hh * hh / 280.0
            f[series] = (1.0 + c2 * (z2 - 1.0) + c4 * ((z2 - 6.0) * z2 + 3.0)) * p / sc
            df[series] = -zc * (1.0 + c2 * (z2 - 3.0) + c4 * ((z2 - 10.0) * z2 + 15.0)) * p / (sc * sc)
    full = finite & ~series
    if full.any():
        every = full.all()
        uu, ee = (u, e) if every else (u[full], e[full])
        sc = ss if np.ndim(ss) == 0 or every else ss[full]
        z1 = (uu - ee) / sc
        z2 = (uu + ee) / sc
        alpha = uu / ee
        beta = -sc / ee
        p1, p2 = _phi(z1), _phi(z2)
        n1 = ndtr(z1)
        m0 = ndtr(z2) - n1
        m1 = p1 - p2
        zp1, zp2 = z1 * p1, z2 * p2
        m2 = m0 + zp1 - zp2
        a2 = alpha * alpha
        b2 = beta * beta
        if cdf:
            m3 = 2.0 * m1 + z1 * zp1 - z2 * zp2
            poly = (2.0 + 3.0 * alpha - a2 * alpha) * m0 + 3.0 * beta * (1.0 - a2) * m1 - 3.0 * alpha * b2 * m2 - b2 * beta * m3
            res = n1 + 0.25 * poly
            if every:
                out = res
            else:
                out[full] = res
        if density:
            f[full] = (0.75 / ee) * ((1.0 - a2) * m0 - 2.0 * alpha * beta * m1 - b2 * m2)
            df[full] = (-1.5 / (ee * ee)) * (alpha * m0 + beta * m1)
    parts = [np.clip(out, 0.0, 1.0)] if cdf else []
    return (parts + [f, df]) if density else parts[0]


def epan_gauss_interval(a, b, e, s) -> NDArray[np.float64]:
    """P(a < e E + s Z <= b) (s a scalar or one per element); the distribution is
    symmetric, so each interval is taken from the tail it lies in (no 1 - 1 cancellation)."""
    a, b, e = np.broadcast_arrays(*(np.asarray(v, float) for v in (a, b, e)))
    upper = (a + b) > 0
    lo = np.where(upper, -b, a)
    hi = np.where(upper, -a, b)
    return np.maximum(epan_gauss_cdf(hi, e, s) - epan_gauss_cdf(lo, e, s), 0.0)


def epan_gauss_density(u, e, s) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(f, f') = the first two u-derivatives of :func:`epan_gauss_cdf` (e > 0, s > 0 a
    scalar or one per element; 0 at u = +-inf), for the likelihood's analytic derivatives.

    f = (3 / 4e) E[1 - x^2; z1 < Z < z2] and f' = -(3 / 2e^2) E[x; z1 < Z < z2], x = (u - sZ)/e
    (the end-point terms vanish or cancel), in the same partial moments as the CDF; below
    e/s = SERIES_BELOW the u-derivatives of the CDF's series (h = e/s, z = u/s):
    s f = [1 + (h^2/10) He2 + (h^4/280) He4] phi(z), s^2 f' = -[He1 + (h^2/10) He3 + (h^4/280) He5] phi(z).
    The derivatives in e and s follow from these (Gaussian integration by parts):
    dF/de = -(u f + s^2 f')/e and dF/ds = s f'.
    """
    u = np.asarray(u, dtype=np.float64)
    e = np.broadcast_to(np.asarray(e, dtype=np.float64), u.shape)
    return tuple(_epan_gauss(u, e, s, False, True))


_X8, _W8 = np.polynomial.legendre.leggauss(8)


def _nodes(n: int):
    x, w = (_X8, _W8) if n == 8 else np.polynomial.legendre.leggauss(n)
    theta = (x + 1.0) * (math.pi / 2.0)
    frac = (1.0 - np.cos(theta)) / 2.0  # tau = a + (c - a) frac
    weight = w * (math.pi / 2.0) * np.sin(theta) / 2.0 * (3.0 / math.pi)
    return frac, weight


_NODES = {8: _nodes(8)}


#: Gauss-Legendre nodes of ball_disk_cdf (8: error < 3e-7; the accuracy/time table in
#: docs/performance.md compares 24).
G_NODES = 8


def ball_disk_cdf(t, gamma, nodes: int | None = None, grad: bool = False, density: bool = False):
    """P(|gamma e_x + n| <= t), n the projection of a uniform unit-3-ball point on a plane.

    In polar coordinates about the noise centre (radius tau), the circle of radius tau
    lies inside the disk |. + gamma e_x| <= t for tau <= t - gamma, outside for
    tau <= gamma - t or tau >= t + gamma, and in between covers an angle
    2 arccos((tau^2 + gamma^2 - t^2) / (2 gamma tau)). The inside part integrates in
    closed form, 1 - (1 - a^2)^(3/2); the partial band a < tau < c is integrated with
    tau = a + (c - a)(1 - cos theta)/2, which makes the square-root ends smooth.

    With ``grad``: (G, t dG/dt, gamma dG/dgamma). Differentiating under the integral (the
    end-point terms cancel or vanish), with Q = (tau^2 - |t - gamma|^2)((t + gamma)^2 - tau^2),

        t dG/dt = (3/pi) int 2 t^2 tau sqrt(1 - tau^2) / sqrt(Q) dtau,
        gamma dG/dgamma = -(3/pi) int tau sqrt(1 - tau^2) (t^2 + gamma^2 - tau^2) / sqrt(Q) dtau,

    over the same band and nodes (the substitution turns the 1/sqrt ends of Q into smooth
    integrands). These are the exact derivatives of G by the same rule, not the derivatives
    of the 8-node value: they differ by the rule's error, a smooth function of (t, gamma).

    With ``density``: t dG/dt alone (half the work of ``grad``; no G), for
    :func:`pose_error.signal_error_bin`.
    """
    nodes = G_NODES if nodes is None else nodes
    t = np.asarray(t, dtype=np.float64)
    gamma = np.maximum(np.asarray(gamma, dtype=np.float64), 1e-300)
    t = np.clip(t, 0.0, gamma + 2.0)  # G = 1 beyond gamma + 1; keeps everything finite
    if nodes not in _NODES:
        _NODES[nodes] = _nodes(nodes)
    frac, weight = _NODES[nodes]
    a = np.abs(t - gamma)
    c = np.minimum(t + gamma, 1.0)
    ac = np.minimum(a, 1.0)
    out = 1.0 - (1.0 - ac * ac) ** 1.5
    out *= t > gamma
    width = np.maximum(c - a, 0.0)
    # Only a band of non-zero width needs the quadrature: in a fit about half the
    # elements have none (G is 0 or 1 there), so gather the others first.
    band = np.flatnonzero(width > 0.0)
    if band.size == 0:
        if density:
            return np.zeros(out.shape)
        out = np.clip(out, 0.0, 1.0)
        return (out, np.zeros(out.shape), np.zeros(out.shape)) if grad else out
    whole = band.size == width.size
    if not whole:
        gamma = np.broadcast_to(gamma, width.shape)
        t, gamma, a, width = (np.ravel(v)[band] for v in (t, gamma, a, width))
    if density:
        return _band_density(t, gamma, a, width, frac, weight, band, whole, out.shape)
    shape = t.shape
    t, gamma, a, width = (np.ravel(np.broadcast_to(v, shape)) for v in (t, gamma, a, width))
    acc = np.empty(t.shape)
    if grad:
        d_tb = np.empty(t.shape)
        d_gb = np.empty(t.shape)
    for sl in _chunks(t.shape[0]):
        if grad:
            acc[sl], d_tb[sl], d_gb[sl] = _band_chunk(t[sl], gamma[sl], a[sl], width[sl], frac, weight, True)
        else:
            acc[sl] = _band_chunk(t[sl], gamma[sl], a[sl], width[sl], frac, weight, False)
    if whole:
        out += acc.reshape(shape)
    else:
        out.ravel()[band] += acc  # out is a fresh contiguous array: ravel() is a view
    out = np.clip(out, 0.0, 1.0)
    if not grad:
        return out
    full = shape if whole else out.shape
    return out, _unband(d_tb, band, whole, full), _unband(d_gb, band, whole, full)


#: The band loops of :func:`ball_disk_cdf` run over this many elements at a time: their
#: dozen temporaries then stay in a core's L2 cache (1e5-row gradient pass: the loop's
#: CPU time -20 % against whole arrays of ~1e5). Same values, element by element.
CHUNK = 16384


def _chunks(n: int):
    return [slice(i, min(i + CHUNK, n)) for i in range(0, n, CHUNK)]


def _band_chunk(t, gamma, a, width, frac, weight, grad):
    """The band integral of :func:`ball_disk_cdf` (times the band width) for band elements
    (1-D), with ``grad`` also (t dG/dt, gamma dG/dgamma)."""
    if grad:
        cp = t + gamma
        over = cp - np.minimum(cp, 1.0)  # (t + gamma) - c: the top of the band below t + gamma
        s1 = np.zeros(t.shape)
        sg = np.zeros(t.shape)
        t2g2 = t * t + gamma * gamma
        b1 = np.empty(t.shape)
        b2 = np.empty(t.shape)
    k = gamma * gamma - t * t
    two_g = 2.0 * gamma
    acc = np.zeros(t.shape)
    tau = np.empty(t.shape)
    z = np.empty(t.shape)
    sq = np.empty(t.shape)
    den = np.empty(t.shape)
    for f, w in zip(frac, weight):
        _node_tau(width, f, a, tau, sq)
        np.add(sq, k, out=z)
        np.multiply(two_g, tau, out=den)
        np.maximum(den, 1e-300, out=den)  # only where the band has zero width
        np.divide(z, den, out=z)
        np.clip(z, -1.0, 1.0, out=z)
        np.arccos(z, out=z)
        _tau_chord(tau, sq)
        if grad:
            s1 += _density_node(tau, a, width, f, w, over, cp, sq, b1, b2)
            np.multiply(tau, tau, out=b2)
            np.subtract(t2g2, b2, out=b2)
            b2 *= b1
            sg += b2
        sq *= z
        sq *= w
        acc += sq
    acc *= width
    if not grad:
        return acc
    return acc, 2.0 * t * t * width * s1, -width * sg


def _node_tau(width, f, a, tau, sq):
    """A quadrature node of the band, in place: tau = a + width f and sq = tau^2."""
    np.multiply(width, f, out=tau)
    tau += a
    np.multiply(tau, tau, out=sq)


def _tau_chord(tau, sq):
    """sq = tau sqrt(1 - tau^2) in place, from sq = tau^2 (0 where |tau| >= 1)."""
    np.subtract(1.0, sq, out=sq)
    np.maximum(sq, 0.0, out=sq)
    np.sqrt(sq, out=sq)
    sq *= tau


def _density_node(tau, a, width, f, w, over, cp, sq, b1, b2):
    """One node's term of t dG/dt (the ``grad`` loop's first sum), in ``b1``: w tau
    sqrt(1 - tau^2) / sqrt(Q) with ``sq`` = tau sqrt(1 - tau^2) and Q's factors formed
    without cancellation (tau - a = width f, (t + gamma) - tau = width (1 - f) + over)."""
    np.multiply(width, f, out=b1)  # tau - a
    np.add(tau, a, out=b2)
    b1 *= b2
    np.multiply(width, 1.0 - f, out=b2)  # (t + gamma) - tau
    b2 += over
    b1 *= b2
    np.add(cp, tau, out=b2)
    b1 *= b2
    np.maximum(b1, 1e-300, out=b1)
    np.sqrt(b1, out=b1)
    np.divide(sq, b1, out=b1)
    b1 *= w
    return b1


def _band_density(t, gamma, a, width, frac, weight, band, whole, shape):
    """t dG/dt of :func:`ball_disk_cdf` on its band elements (the ``grad`` loop's first sum)."""
    cp = t + gamma
    over = cp - np.minimum(cp, 1.0)
    s1 = np.zeros(t.shape)
    tau = np.empty(t.shape)
    sq = np.empty(t.shape)
    b1 = np.empty(t.shape)
    b2 = np.empty(t.shape)
    for f, w in zip(frac, weight):
        _node_tau(width, f, a, tau, sq)
        _tau_chord(tau, sq)
        s1 += _density_node(tau, a, width, f, w, over, cp, sq, b1, b2)
    return _unband(2.0 * t * t * width * s1, band, whole, shape)


def _unband(values, band, whole, shape):
    """Per-band-element ``values`` as an array of ``shape``: 0 off the band."""
    if whole:
        return values.reshape(shape)
    full = np.zeros(shape)
    full.ravel()[band] = values
    return full

#: Rows within this many standard deviations of a kink of ball_disk_cdf get the
#: piecewise rule; the others the 3-point Gauss-Hermite rule.
Z_KINK = 6.0
Z_BLEND = 2.0
Z_SPAN = 8.0  # the piecewise rule integrates over [-Z_SPAN, Z_SPAN]
#: Longest piece of the piecewise rule (standard deviations); 6 Gauss-Legendre nodes each.
PIECE = 2.0
_GH3_X = np.array([-math.sqrt(3.0), 0.0, math.sqrt(3.0)])
_GH3_W = np.array([1.0, 4.0, 1.0]) / 6.0
_GH2_X = np.array([-1.0, 1.0])
_GH2_W = np.array([0.5, 0.5])
#: The 2-point rule is used where s3 is below this fraction of the distance between the kinks.
GH2_BELOW = 0.01
_XP, _WP = np.polynomial.legendre.leggauss(6)


def smoothed_ball_disk_cdf(log_t, gamma, s3, grad: bool = False):
    """E[G(t exp(s3 Z); gamma)], Z standard normal: :func:`ball_disk_cdf` seen through a
    log-normal error of the threshold (the pose error, s3 = 3 sigma in log |h|; a scalar
    or one per row).

    G(.; gamma) is smooth except at t = |gamma - 1| and t = gamma + 1, where its support
    starts (gamma > 1) and ends: there 1 - G or G grows like a square, so without the pose
    error every row next to an edge is a log barrier for the parameters. Rows farther than
    ``Z_KINK`` standard deviations from both kinks use the 3-point Gauss-Hermite rule
    (exact to O(s3^6)). For the others, with z1 < z2 the kinks in units of s3: G = 1
    above z2, which contributes exactly 1 - Phi(z2); G = 0 below z1 when gamma > 1; only
    the stretch of [-Z_SPAN, Z_SPAN] where G is neither is integrated, split at z1 (when
    gamma < 1) into pieces no longer than ``PIECE`` standard deviations, 6 Gauss-Legendre
    nodes each. The pose error usually dwarfs the support of G (a few s.d.), so most
    rows need one or two pieces. What lies beyond +-Z_SPAN (< 1e-15) is left out: the
    likelihood's gross-error floor (~2e-10) is far above it.

    With ``grad``: (C, dC/dlog t, dC/dlog gamma, dC/ds3), each rule applied to
    :func:`ball_disk_cdf`'s derivatives (dC/ds3 = E[Z dG/dlog t]); the piecewise rule's
    moving ends add nothing (G = 0 at z1 when gamma > 1, G = 1 at z2 against the
    1 - Phi(z2) term), and the blend's weight contributes its own derivative.
    """
    log_t = np.asarray(log_t, dtype=np.float64)
    gamma = np.asarray(gamma, dtype=np.float64)
    if np.ndim(s3) == 0 and not s3 > 0:
        if grad:
            g0, d_t, d_g = ball_disk_cdf(np.exp(np.minimum(log_t, 700.0)), gamma, grad=True)
            return g0, d_t, d_g, np.zeros(g0.shape)
        return ball_disk_cdf(np.exp(np.minimum(log_t, 700.0)), gamma)
    s3 = np.broadcast_to(np.asarray(s3, dtype=np.float64), log_t.shape)
    with np.errstate(divide="ignore"):
        z1 = (np.log(np.abs(gamma - 1.0)) - log_t) / s3
        z2 = (np.log(gamma + 1.0) - log_t) / s3
    zmin = np.minimum(np.abs(z1), np.abs(z2))
    out = np.empty(log_t.shape)
    d = np.zeros((3,) + log_t.shape) if grad else None  # d/dlog t, d/dlog gamma, d/ds3
    # Away from the kinks G is smooth: the 3-point Gauss-Hermite rule (exact for
    # polynomials of degree 5 in z) is accurate to (s3 / spread)^6. One call for all nodes.
    # When s3 is under GH2_BELOW of the distance between the kinks (exact poses: 3e-4
    # against >= 0.06), the 2-point rule (exact to degree 3, error s3^4 G^(4) / 12 < 1e-9)
    # does as well with a node less.
    far = zmin >= Z_KINK
    two = far & (z2 - z1 >= 1.0 / GH2_BELOW)
    for rows, xs, ws in ((np.flatnonzero(far & ~two), _GH3_X, _GH3_W), (np.flatnonzero(two), _GH2_X, _GH2_W)):
        if rows.size:
            lt, g, sc = log_t[rows], gamma[rows], s3[rows]
            nodes = np.minimum(lt[:, None] + sc[:, None] * xs, 700.0)
            if grad:
                gv, d_t, d_g = ball_disk_cdf(np.exp(nodes), np.broadcast_to(g[:, None], nodes.shape), grad=True)
                out[rows] = gv @ ws
                d[0, rows], d[1, rows], d[2, rows] = d_t @ ws, d_g @ ws, d_t @ (xs * ws)
            else:
                out[rows] = ball_disk_cdf(np.exp(nodes), np.broadcast_to(g[:, None], nodes.shape)) @ ws
    near = np.flatnonzero(zmin < Z_KINK + Z_BLEND)
    if not near.size:
        return (out, *d) if grad else out
    acc = _piecewise(log_t[near], gamma[near], s3[near], z1[near], z2[near], grad=grad)
    # Between Z_KINK and Z_KINK + Z_BLEND the two rules are blended with a C2 smooth step,
    # so the likelihood has no jump where a row changes rule (they differ by ~1e-7).
    x = np.clip((zmin[near] - Z_KINK) / Z_BLEND, 0.0, 1.0)
    w = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
    gh = np.where(w > 0.0, out[near], 0.0)  # out[near] is set only where w > 0
    if not grad:
        out[near] = np.clip(w * gh + (1.0 - w) * acc, 0.0, 1.0)
        return out
    acc, acc_d = acc
    out[near] = np.clip(w * gh + (1.0 - w) * acc, 0.0, 1.0)
    # d zmin: z1, z2 = (log|gamma -+ 1| - log t) / s3
    zn1, zn2, gn, sn = z1[near], z2[near], gamma[near], s3[near]
    first = np.abs(zn1) <= np.abs(zn2)
    zm = np.where(first, zn1, zn2)
    sign = np.sign(zm) / sn
    with np.errstate(divide="ignore", invalid="ignore"):
        dlg = np.where(first, gn / (gn - 1.0), gn / (gn + 1.0))
    dw = (30.0 / Z_BLEND) * (x * (1.0 - x)) ** 2 * (gh - acc)
    dz = (-sign, sign * dlg, -sign * zm)
    for i in range(3):
        dgh = np.where(w > 0.0, d[i, near], 0.0)
        blend = np.where(dw != 0.0, dw * dz[i], 0.0)
        d[i, near] = w * dgh + (1.0 - w) * acc_d[i] + blend
    return (out, *d)


def normal_pieces(lo, mid, hi, piece: float | None = None, nodes: int | None = None):
    """Nodes for E[f(Z); lo < Z < hi], Z standard normal, one interval per row split at
    ``mid`` (a kink of f) into pieces of at most ``piece`` (default :data:`PIECE`) s.d.,
    ``nodes`` (default 6) Gauss-Legendre nodes each: (row, z, wz), the piece's row and its
    nodes and weights (pieces, nodes), so that ``bincount(row, weights=(wz * f(z)).sum(1))``
    is the expectation per row."""
    piece = PIECE if piece is None else piece
    xp, wp = (_XP, _WP) if nodes is None else _legendre(nodes)
    ka = np.ceil((mid - lo) / piece).astype(np.int64)
    kb = np.ceil((hi - mid) / piece).astype(np.int64)
    kt = ka + kb
    row = np.repeat(np.arange(lo.shape[0]), kt)
    j = np.arange(row.shape[0]) - np.repeat(np.cumsum(kt) - kt, kt)  # piece number within its row
    ka_r, kb_r = ka[row], kb[row]
    in_a = j < ka_r
    wa = (mid - lo)[row] / np.maximum(ka_r, 1)
    wb = (hi - mid)[row] / np.maximum(kb_r, 1)
    width = np.where(in_a, wa, wb)
    left = np.where(in_a, lo[row] + j * wa, mid[row] + (j - ka_r) * wb)
    half = 0.5 * width
    z = (left + half)[:, None] + half[:, None] * xp  # (pieces, nodes)
    wz = (half[:, None] * wp) * (_INV_SQRT_2PI * np.exp(-0.5 * z * z))
    return row, z, wz


_LEGENDRE: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}


def _legendre(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The n-point Gauss-Legendre nodes and weights on [-1, 1] (kept)."""
    if n not in _LEGENDRE:
        _LEGENDRE[n] = np.polynomial.legendre.leggauss(n)
    return _LEGENDRE[n]


def _piecewise(lt, g, s3, z1, z2, w=None, grad=False):
    """E[G(exp(lt + s3 Z); g)] by integrating only where 0 < G < 1 (see
    :func:`smoothed_ball_disk_cdf`); all arguments one per row. With ``w``:
    E[G(...) (w He1 + w^3/24 He3 + w^5/1920 He5)(Z)] instead (:func:`smoothed_ball_disk_bin`).
    With ``grad`` (and no ``w``): (value, its derivatives in log t, log gamma and s3)."""
    lo = np.where(g > 1.0, np.clip(z1, -Z_SPAN, Z_SPAN), -Z_SPAN)  # G = 0 below z1 if g > 1
    hi = np.maximum(np.clip(z2, -Z_SPAN, Z_SPAN), lo)  # G = 1 above z2
    mid = np.clip(z1, lo, hi)  # the other kink (inside only when g < 1)
    row, z, wz = normal_pieces(lo, mid, hi)
    if w is not None:
        wr = w[row][:, None]
        z2_ = z * z
        wz *= wr * z + (wr**3 / 24.0) * (z2_ - 3.0) * z + (wr**5 / 1920.0) * ((z2_ - 10.0) * z2_ + 15.0) * z
    with np.errstate(over="ignore"):
        tz = np.exp(np.minimum(lt[row][:, None] + s3[row][:, None] * z, 700.0))
    if grad:
        gz, g_t, g_g = ball_disk_cdf(tz, np.broadcast_to(g[row][:, None], tz.shape), grad=True)
    else:
        gz = ball_disk_cdf(tz, np.broadcast_to(g[row][:, None], tz.shape))
    acc = np.bincount(row, weights=np.einsum("ij,ij->i", wz, gz), minlength=lt.shape[0])
    if grad:
        n = lt.shape[0]
        d = [np.bincount(row, weights=np.einsum("ij,ij->i", wz, v), minlength=n) for v in (g_t, g_g, z * g_t)]
        return acc + ndtr(-np.maximum(z2, -40.0)), d
    if w is None:
        return acc + ndtr(-np.maximum(z2, -40.0))  # G = 1 above z2
    zt = np.clip(z2, -40.0, 40.0)
    zz = zt * zt
    tail = (w + (w**3 / 24.0) * (zz - 1.0) + (w**5 / 1920.0) * ((zz - 6.0) * zz + 3.0)) * _phi(zt)
    return acc + tail


#: :func:`smoothed_ball_disk_bin` is used for bins narrower than this many standard
#: deviations of the pose error (its series' first neglected term is ~ w^6 / 3e5 of P).
BIN_W_MAX = 0.2


def smoothed_ball_disk_bin(mid, delta, gamma, s3) -> NDArray[np.float64]:
    """P(mid - delta/2 < log |h| + s3 Z <= mid + delta/2) = C(mid + delta/2) - C(mid - delta/2),
    C the :func:`smoothed_ball_disk_cdf`, for a bin narrow against s3 (w = delta / s3 <=
    BIN_W_MAX; all arguments one per row): one set of nodes instead of two and no
    cancellation. With C^(n+1)(m) = E[He_n(Z) G(m + s3 Z)] / s3^n (Hermite polynomials,
    Gaussian integration by parts) the odd Taylor series of the difference about m is

        P = E[G(m + s3 Z) (w He1(Z) + w^3/24 He3(Z) + w^5/1920 He5(Z))] + O(w^7).

    The expectation uses the rules of :func:`smoothed_ball_disk_cdf` (above z2 G = 1:
    E[He_n(Z); Z > z2] = He_(n-1)(z2) phi(z2)), except far from both kinks, where the
    two 3-point Gauss-Hermite values are differenced as there (He3 and He5 vanish at
    its nodes)."""
    mid = np.asarray(mid, dtype=np.float64)
    gamma = np.asarray(gamma, dtype=np.float64)
    s3 = np.broadcast_to(np.asarray(s3, dtype=np.float64), mid.shape)
    w = np.asarray(delta, dtype=np.float64) / s3
    with np.errstate(divide="ignore"):
        z1 = (np.log(np.abs(gamma - 1.0)) - mid) / s3
        z2 = (np.log(gamma + 1.0) - mid) / s3
    zmin = np.minimum(np.abs(z1), np.abs(z2))
    out = np.empty(mid.shape)
    far = np.flatnonzero(zmin >= Z_KINK)
    if far.size:
        m, g, sc, half = mid[far], gamma[far], s3[far], 0.5 * w[far] * s3[far]
        nodes = np.concatenate([m + half, m - half])[:, None] + np.concatenate([sc, sc])[:, None] * _GH3_X
        vals = ball_disk_cdf(np.exp(np.minimum(nodes, 700.0)), np.broadcast_to(np.concatenate([g, g])[:, None], nodes.shape)) @ _GH3_W
        out[far] = vals[: far.size] - vals[far.size :]
    near = np.flatnonzero(zmin < Z_KINK + Z_BLEND)
    if not near.size:
        return np.maximum(out, 0.0)
    acc = _piecewise(mid[near], gamma[near], s3[near], z1[near], z2[near], w[near])
    x = np.clip((zmin[near] - Z_KINK) / Z_BLEND, 0.0, 1.0)
    bw = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
    gh = np.where(bw > 0.0, out[near], 0.0)
    out[near] = bw * gh + (1.0 - bw) * acc
    return np.maximum(out, 0.0)
