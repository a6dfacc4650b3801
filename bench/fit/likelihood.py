"""The likelihood of the observed integers d given each row's geometry (BRIEF 3, 3.2).

For row i the logged poses give the distance r and the receiver-frame field direction
g = R_r^T R_t A(p)/r^2 (|g| in [1, 2]); with s = 1 the signal is c = g / (4 pi r^3). The
receiver adds EMI n = Q R_r^T w, w uniform in the ball of radius w_en = 1/(2 pi max q r_en^3),
and shows

    inner  d = round(100 d3)  if d3 = cbrt(kappa / (4 pi |h|)) <= r_inner
    mid    d = round(100 dxy) if dxy = cbrt(kappa / (4 pi |h_xy|)) <= r_outer
    outer  d = -1

The model multiplies both distances by exp(sigma Z), Z standard normal: the error of the
logged poses (``pose_sigma``, relative; fixed at 0.1 % unless fitted). Then for each row

    P(d = k) = P(inner, round(100 d3) = k) + (1 - P(inner)) P(round(100 dxy) = k, dxy <= r_outer)
    P(d = -1) = (1 - P(inner)) P(dxy > r_outer)

(the censored rows carry as much information as the detected ones). Two evaluations of
the distribution of log dxy are used, chosen per row once per pass (regimes are frozen
during an optimisation so the objective stays smooth):

* **S** (EMI small against the signal, eps = |noise radius| / |c_xy| <= ``eps_split``):
  log dxy = log dxy0 - (eps/3) E + sigma Z with E the ball's projection on a line; the
  CDF is closed form (:func:`special.epan_gauss_cdf`). The neglected terms are O(eps^2).
* **L** (otherwise): the exact distribution of |h_xy| under ball noise
  (:func:`special.ball_disk_cdf`); the pose error is added by a Gauss-Hermite rule only
  when it is being fitted or set above 0.2 % (with eps > eps_split the EMI spread of
  log d is >= 10 times a 0.1 % pose error's).

The inner zone always uses S on |h| (EMI is 1e-4 of the signal at 3 m). Every
probability is mixed with a gross-error floor: P' = (1 - 1e-6) P + 1e-6 / (100 r_outer + 2).
Only kappa_eq / s is identifiable: the fit reports kappa_eq for s = 1.

Analytic first derivatives (:meth:`Likelihood.logp_grad`) of every row's log P in
(log kappa_eq, log r_en, log pose_sigma) come from the same pass, for exact poses (no
errors-in-variables sigmas): kappa_eq moves every log distance by 1/3 of its log; r_en
scales the EMI spread e of the S rule as r_en^-3 and both the threshold t and gamma of the
L rule as r_en^3; pose_sigma is the s.d. s of the Gaussian part. With f = dF/du the
density of the S rule's CDF F(u; e, s), Gaussian integration by parts gives
dF/dlog r_en = 3 (u f + s^2 f') and dF/dlog s = s^2 f'; the L rule differentiates
:func:`special.ball_disk_cdf` under its integral.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .pose_error import BIN_W_MAX as SIGNAL_BIN_W_MAX, signal_error_bin, signal_error_cdf
from .special import (
    epan_gauss_cdf,
    epan_gauss_density,
    epan_gauss_interval,
    smoothed_ball_disk_bin,
    smoothed_ball_disk_cdf,
)
from .params import FREE_PARAMS, LINEAR, Params, from_params, to_params  # noqa: F401 (re-exported)
from .rows import Geometry, PoseTrack, Rows, geometry, mounted, rows_from_table  # noqa: F401 (re-exported)

GROSS_ERROR = 1e-6
EPS_SPLIT = 0.03
#: A Likelihood with ``block`` > 0 evaluates its rows in blocks of that many (the arrays
#: of the near-kink rule then stay in cache: 1e5 rows with pose error 1.75x faster in
#: blocks of 1e4), on two threads when ``threads`` is 2 and the main thread asks (numpy
#: releases the GIL). Every row is computed as it would be in one piece: same values, bit
#: for bit. The fit uses BLOCK_ROWS on all rows.
BLOCK_ROWS = 10000
_row_pool: ThreadPoolExecutor | None = None
_row_pool_lock = threading.Lock()


def _rows_pool() -> ThreadPoolExecutor:
    global _row_pool
    with _row_pool_lock:
        if _row_pool is None:
            _row_pool = ThreadPoolExecutor(2, thread_name_prefix="fit-rows")
    return _row_pool


@dataclass
class Regimes:
    """Which rows use the exact (L) evaluation; frozen for one optimisation pass."""

    exact: NDArray[np.bool_]
    eps_split: float = EPS_SPLIT
    #: exact rows whose bin is narrow against the pose error (pose_error.BIN_W_MAX): one
    #: density at the bin's middle instead of two CDFs (:func:`pose_error.signal_error_bin`)
    narrow: NDArray[np.bool_] | None = None


def _log_eps(geo_log_r, log_gn, qfac, r_en):
    """log of noise radius / signal = log(2 qfac r^3 / (r_en^3 |g|))."""
    with np.errstate(divide="ignore"):
        return np.log(2.0 * qfac) + 3.0 * (geo_log_r - math.log(r_en)) - log_gn


def _qfactors(g: NDArray[np.float64], q) -> tuple[NDArray, NDArray]:
    """|Q g_hat| / max q in the xy plane and in 3D (the noise radius along the signal)."""
    qx, qy, qz = (v / max(q) for v in q)
    gx, gy, gz = g
    gxy2 = gx * gx + gy * gy
    g2 = gxy2 + gz * gz
    with np.errstate(invalid="ignore", divide="ignore"):
        fxy = np.sqrt((qx * qx * gx * gx + qy * qy * gy * gy) / gxy2)
        f3 = np.sqrt((qx * qx * gx * gx + qy * qy * gy * gy + qz * qz * gz * gz) / g2)
    fxy = np.where(gxy2 > 0, fxy, math.sqrt((qx * qx + qy * qy) / 2.0))
    return fxy, f3


class Likelihood:
    """log P(d_i | geometry_i, params) for every row, vectorised over rows."""

    def __init__(self, rows: Rows, regimes: Regimes | None = None) -> None:
        self.rows = rows
        self.k = rows.k
        self.censored = rows.k == -1
        self.regimes = regimes
        self.n_evals = 0
        self._count = threading.Lock()  # the fit evaluates a stencil's points on several threads
        #: How many per-row results :meth:`logp` keeps, by parameters (0: none). The fit's
        #: full-data stage sets it: the sandwich's scores are the last gradient's points.
        self.remember = 0
        self._memo: dict = {}
        #: rows per block (0: one piece) and threads for the blocks (see BLOCK_ROWS)
        self.block = 0
        self.threads = 1
        self._blocks: tuple | None = None
        self._fixed_memo: tuple | None = None  # (geometry, q, k, arrays) of :meth:`_fixed`

    def choose_regimes(self, p: Params, eps_split: float = EPS_SPLIT) -> Regimes:
        geo = self.geometry(p)
        gx, gy, _ = geo.g
        with np.errstate(divide="ignore"):
            log_gxy = np.log(np.hypot(gx, gy))
        fxy, _ = _qfactors(geo.g, p.q)
        exact = _log_eps(geo.log_r, log_gxy, fxy, p.r_en) > math.log(eps_split)
        narrow = None
        if self.rows.moments is not None and (p.gps_sigma > 0.0 or p.attitude_sigma > 0.0):
            sigma = self.pose_spread(p, 0.0, 0.0)[0]
            kk = np.maximum(self.k, 1).astype(np.float64)
            # (the errors-in-variables branch of mid_prob: pose_error.signal_error_bin)
            scale = sigma * np.minimum(_gamma(geo.log_r, log_gxy, fxy, p.r_en), 1.0)
            narrow = exact & (self.k >= 1) & (np.log((kk + 0.5) / (kk - 0.5)) < SIGNAL_BIN_W_MAX * scale)
        self.regimes = Regimes(exact, eps_split, narrow)
        self._memo.clear()
        return self.regimes

    def geometry(self, p: Params) -> Geometry:
        """The rows' geometry under ``p``: at its time offset, with its mounting bias and
        antennas (what :meth:`prob` evaluates)."""
        geo = self.rows.track.geometry(p.time_offset) if p.time_offset != 0.0 and self.rows.track is not None else self.rows.geo
        if p.mount_pitch != 0.0 or p.mount_roll != 0.0:
            geo = mounted(geo, p.mount_pitch, p.mount_roll)
        return geo if p.antennas == 3 else Geometry(geo.log_r, geo.g * np.array([[1.0], [1.0], [0.0]]))

    def logp(self, p: Params) -> NDArray[np.float64]:
        """log P(d_i) for each row, gross-error floor included (the array may be shared:
        do not write to it)."""
        key = self._key(p)
        hit = self.remembered(p)
        if hit is not None:
            return hit
        with self._count:
            self.n_evals += 1
        prob = self._prob_blocks(p) if self._split() else self.prob(p)
        if p.dropout > 0.0:  # a row reads -1 with this probability whatever the signal
            prob = (1.0 - p.dropout) * prob + p.dropout * self.censored
        n_out = 100.0 * p.r_outer + 2.0
        out = np.log((1.0 - GROSS_ERROR) * prob + GROSS_ERROR / n_out)
        self._keep(key, out)
        return out

    def _key(self, p: Params):
        """The memo's key of ``p`` under the current regimes."""
        return (p, None if self.regimes is None else id(self.regimes.exact))

    def _keep(self, key, out) -> None:
        """Keep ``out`` (log P per row) under ``key`` when :attr:`remember` asks for it."""
        if self.remember:
            with self._count:
                while len(self._memo) >= self.remember:
                    self._memo.pop(next(iter(self._memo)))
                self._memo[key] = (None if self.regimes is None else self.regimes.exact, out)

    def remembered(self, p: Params) -> NDArray[np.float64] | None:
        """The per-row log P at ``p`` that :meth:`logp` kept (see :attr:`remember`), or None."""
        hit = self._memo.get(self._key(p)) if self.remember else None
        if hit is not None and (self.regimes is None or hit[0] is self.regimes.exact):
            return hit[1]
        return None

    def record(self, p: Params, out: NDArray[np.float64]) -> None:
        """Count ``out``, the per-row log P at ``p`` computed elsewhere from this
        likelihood's rows and regimes (the fit's worker process, :mod:`.worker`), as an
        evaluation, and keep it as :meth:`logp` would have."""
        with self._count:
            self.n_evals += 1
        self._keep(self._key(p), out)

    def nll(self, p: Params) -> float:
        return -float(np.sum(self.logp(p)))

    #: The parameters :meth:`logp_grad` differentiates by, in the optimiser's (log) scale.
    GRAD_PARAMS = ("kappa_eq", "r_en", "pose_sigma")

    def has_grad(self, p: Params) -> bool:
        """Whether :meth:`logp_grad` applies: the pose error is the scalar pose_sigma (no
        errors-in-variables sigmas or height offset, no narrow-bin rows) and the rules are
        this class's own."""
        mom_free = self.rows.moments is None or (p.gps_sigma == 0.0 and p.attitude_sigma == 0.0 and p.height_offset == 0.0)
        narrow = self.regimes is not None and self.regimes.narrow is not None and bool(self.regimes.narrow.any())
        plain = type(self).mid_prob is Likelihood.mid_prob and p.pose_sigma > 0.0 and p.dropout == 0.0 and p.gps_outlier == 0.0
        return mom_free and not narrow and plain

    def logp_grad(self, p: Params) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(log P(d_i), d log P(d_i) / d(log kappa_eq, log r_en, log pose_sigma)) per row,
        the second of shape (3, N), from one pass (see the module docstring; needs
        :meth:`has_grad`). Counts as one evaluation."""
        if not self.has_grad(p):
            raise ValueError("analytic derivatives need exact poses (pose_sigma > 0, no errors-in-variables sigmas)")
        with self._count:
            self.n_evals += 1
        prob, dprob = self._prob_blocks(p, True) if self._split() else self.prob(p, grad=True)
        n_out = 100.0 * p.r_outer + 2.0
        mixed = (1.0 - GROSS_ERROR) * prob + GROSS_ERROR / n_out
        out = np.log(mixed)
        self._keep(self._key(p), out)
        return out, dprob * ((1.0 - GROSS_ERROR) / mixed)

    def _split(self) -> bool:
        return self.block > 0 and self.regimes is not None and self.k.shape[0] >= 2 * self.block

    def _prob_blocks(self, p: Params, grad: bool = False):
        """:meth:`prob` block by block (see BLOCK_ROWS)."""
        reg = self.regimes
        if self._blocks is None or self._blocks[0] is not reg.exact or self._blocks[1] is not reg.narrow:
            n = self.k.shape[0]
            parts = []
            for start in range(0, n, self.block):
                sl = slice(start, min(start + self.block, n))
                part = type(self)(self.rows.take(sl))
                part.regimes = Regimes(reg.exact[sl], reg.eps_split, None if reg.narrow is None else reg.narrow[sl])
                parts.append(part)
            self._blocks = (reg.exact, reg.narrow, parts)
        parts = self._blocks[2]
        if self.threads > 1 and threading.current_thread() is threading.main_thread() and len(parts) > 1:
            # two tasks of consecutive blocks (one task per block hands the GIL over too often)
            half = (len(parts) + 1) // 2
            run = lambda group: [part.prob(p, grad) for part in group]  # noqa: E731
            first, second = _rows_pool().map(run, (parts[:half], parts[half:]))
            done = first + second
        else:
            done = [part.prob(p, grad) for part in parts]
        if grad:
            return np.concatenate([v for v, _d in done]), np.concatenate([d for _v, d in done], axis=1)
        return np.concatenate(done)

    # -- the model ------------------------------------------------------------------
    def pose_spread(self, p: Params, l3, lxy, sel=None):
        """(sigma_xy, sigma_3, l3, lxy): the Gaussian spread of log d per zone and the
        noise-free log distances shifted by the pose error's mean effect. Without the
        errors-in-variables model (or with it at zero) sigma is the scalar pose_sigma."""
        mom = self.rows.moments
        if mom is not None and p.height_offset != 0.0:
            dz = mom.dz_3 if sel is None else mom.dz_3[sel]
            dzxy = mom.dz_xy if sel is None else mom.dz_xy[sel]
            l3, lxy = l3 + p.height_offset * dz, lxy + p.height_offset * dzxy
        if mom is None or (p.gps_sigma == 0.0 and p.attitude_sigma == 0.0):
            return p.pose_sigma, p.pose_sigma, l3, lxy
        h, v, a = p.pose_error
        scale = self.rows.gps_scale
        if sel is not None:
            mom = mom.take(sel)
            scale = None if scale is None else scale[sel]
        if scale is None:
            mxy, vxy, m3, v3 = mom.spread((h, v, a))
        else:  # per-row GPS sigmas: h and v scale together
            w = np.stack([(h * scale) ** 2, (v * scale) ** 2, np.full(scale.shape, a * a)])
            mxy, vxy = np.einsum("gn,gn->n", w, mom.m_xy), np.einsum("gn,gn->n", w, mom.v_xy)
            m3, v3 = np.einsum("gn,gn->n", w, mom.m_3), np.einsum("gn,gn->n", w, mom.v_3)
        s2 = p.pose_sigma * p.pose_sigma
        return np.sqrt(s2 + vxy), np.sqrt(s2 + v3), l3 + m3, lxy + mxy

    def prob(self, p: Params, grad: bool = False):
        """P(d_i) per row; with ``grad`` (exact poses, :meth:`has_grad`) also its
        derivatives in (log kappa_eq, log r_en, log pose_sigma), shape (3, N). With
        heavy-tailed GPS error (``p.gps_outlier`` > 0) the mixture of its two components."""
        if p.gps_outlier > 0.0 and not grad:
            return mixed(p, self._prob)
        return self._prob(p, grad)

    def _prob(self, p: Params, grad: bool = False):
        """:meth:`prob` of one pose-error model (no outlier component)."""
        if self.regimes is None:
            self.choose_regimes(p)
        geo = self.geometry(p)
        k = self.k
        n = k.shape[0]
        log_r = geo.log_r
        log_gxy, log_g3, fxy, f3, lo, hi = self._fixed(geo, p.q)
        lk = math.log(p.kappa_eq)
        l3 = log_r + (lk - log_g3) / 3.0  # log d3 without noise
        lxy = log_r + (lk - log_gxy) / 3.0  # log dxy without noise (inf if g_xy = 0)
        lxy0 = lxy
        sigma, sig3, l3, lxy = self.pose_spread(p, l3, lxy)
        e3 = np.exp(_log_eps(log_r, log_g3, f3, p.r_en)) / 3.0
        log_in = math.log(p.r_inner)
        log_out = math.log(p.r_outer)

        prob = np.zeros(n)
        dprob = np.zeros((3, n)) if grad else None

        # Inner part: rows whose bin reaches below r_inner.
        inner = (~self.censored) & (lo <= log_in)
        if inner.any():
            i = inner
            lo_u, hi_u = lo[i] - l3[i], np.minimum(hi[i], log_in) - l3[i]
            if grad:
                p_in, d_in = _interval_value_grad(lo_u, hi_u, e3[i], sig3)
                dprob[:, i] += d_in
            else:
                p_in = epan_gauss_interval(lo_u, hi_u, e3[i], _at(sig3, i))
            prob[i] += p_in

        # Mid part and censoring: P(inner) first, then the distribution of log dxy.
        mid = (self.censored | (hi > log_in)) & ~(lo >= log_out)
        if not mid.any():
            return (prob, dprob) if grad else prob
        idx = np.flatnonzero(mid)
        # P(inner) is exactly 0 to double precision unless d3 is within e3 + 9 sigma of r_inner.
        p_not_inner = np.ones(idx.shape[0])
        gap = log_in - l3[idx]
        s3i = _at(sig3, idx)
        maybe = gap > -(e3[idx] + 9.0 * s3i)
        if maybe.any():
            p_not_inner[maybe] = 1.0 - epan_gauss_cdf(gap[maybe], e3[idx][maybe], _at(s3i, maybe))
        cens = self.censored[idx]
        a = np.where(cens, log_out, np.maximum(lo[idx], log_in))  # P(a < log dxy <= b)
        b = np.where(cens, np.inf, np.minimum(hi[idx], log_out))
        m = _Mid(geo, log_gxy, lxy, fxy, lk, sigma, p, lxy0)
        if not grad:
            prob[idx] += p_not_inner * self.mid_prob(idx, a, b, m)
            return prob
        pm, dpm = self.mid_prob(idx, a, b, m, grad=True)
        prob[idx] += p_not_inner * pm
        if maybe.any():  # elsewhere P(not inner) is 1 and its derivatives 0
            d_pni = -_cdf_grad(gap[maybe], -1.0 / 3.0, e3[idx][maybe], sig3)
            dpm[:, maybe] = d_pni * pm[maybe] + p_not_inner[maybe] * dpm[:, maybe]
        dprob[:, idx] += dpm
        return prob, dprob

    def _fixed(self, geo: Geometry, q):
        """(log |g_xy|, log |g|, fxy, f3, lo, hi) of every row: what :meth:`prob` needs that
        no fitted parameter moves (lo, hi: the log bounds of each row's bin, m); kept for
        the rows' own geometry (every evaluation without a time offset) and ``q``."""
        memo = self._fixed_memo
        if memo is not None and memo[0] is geo and memo[1] == q and memo[2] is self.k:
            return memo[3]
        gx, gy, gz = geo.g
        with np.errstate(divide="ignore"):
            log_gxy = np.log(np.hypot(gx, gy))
            log_g3 = 0.5 * np.log(gx * gx + gy * gy + gz * gz)
        fxy, f3 = _qfactors(geo.g, q)
        kk = self.k.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            lo = np.log((kk - 0.5) / 100.0)  # -inf for k = 0 (and nan for k = -1, unused)
            hi = np.log((kk + 0.5) / 100.0)
        out = (log_gxy, log_g3, fxy, f3, lo, hi)
        if geo is self.rows.geo:
            self._fixed_memo = (geo, q, self.k, out)
        return out

    def mid_prob(self, idx, a, b, m: "_Mid", grad: bool = False):
        """P(a < log dxy <= b) for rows ``idx`` (bounds may be +-inf): S rows in closed
        form, L rows from the exact |h_xy| distribution (with ``grad``: and its
        derivatives, as :meth:`prob`). Subclasses replace this to try other
        approximations (tests/perf/bench_fit.py)."""
        p, sigma = m.params, m.sigma
        log_r = m.geo.log_r
        # the exact rule works in log |h_xy| = log kappa - 3 log dxy: shift the threshold
        log_kappa = m.log_kappa
        pm = np.zeros(idx.shape[0])
        dpm = np.zeros((3, idx.shape[0])) if grad else None
        exact = self.regimes.exact[idx]
        s_rows = ~exact
        if s_rows.any():
            j = idx[s_rows]
            exy = np.exp(_log_eps(log_r[j], m.log_gxy[j], m.fxy[j], p.r_en)) / 3.0
            if grad:
                pm[s_rows], dpm[:, s_rows] = _interval_value_grad(a[s_rows] - m.lxy[j], b[s_rows] - m.lxy[j], exy, sigma)
            else:
                pm[s_rows] = epan_gauss_interval(a[s_rows] - m.lxy[j], b[s_rows] - m.lxy[j], exy, _at(sigma, j))
        if exact.any() and self.rows.moments is not None and (p.gps_sigma > 0.0 or p.attitude_sigma > 0.0):
            # errors in variables (no analytic gradient: has_grad): the pose error moves the
            # signal against fixed EMI (pose_error.signal_error_cdf)
            j = idx[exact]
            log_t0 = log_kappa + 3.0 * math.log(p.r_en) - np.log(2.0 * m.fxy[j])
            s3 = 3.0 * _at(sigma, j)
            ae, be = a[exact], b[exact]
            nar = self.regimes.narrow
            nar = np.zeros(j.shape, bool) if nar is None else nar[j]
            top = np.isfinite(be) & ~nar  # P(log dxy > inf) = 0: censored rows need one value
            wide = ~nar
            pe = np.empty(j.shape)
            with np.errstate(invalid="ignore", divide="ignore"):
                log_g = np.log(_gamma(log_r[j], m.log_gxy[j], m.fxy[j], p.r_en)) - 3.0 * (m.lxy[j] - m.lxy0[j])
                piece = self.rows.moments.piece
                if nar.any():  # one density at the bin's middle instead of two CDFs
                    pe[nar] = signal_error_bin(
                        log_t0[nar] - 1.5 * (ae[nar] + be[nar]), 3.0 * (be[nar] - ae[nar]), log_g[nar], _at(s3, nar), piece
                    )
                if wide.any():
                    above = signal_error_cdf(log_t0[wide] - 3.0 * ae[wide], log_g[wide], _at(s3, wide), piece)
                    tw = top[wide]
                    above[tw] -= signal_error_cdf(log_t0[top] - 3.0 * be[top], log_g[top], _at(s3, top), piece)
                    pe[wide] = np.maximum(above, 0.0)
            pm[exact] = pe
        elif exact.any():
            j = idx[exact]
            # log dxy <= y <=> |h_xy| >= kappa / (4 pi e^{3y}); in units of the noise radius
            # b = fxy / (2 pi r_en^3) that threshold is t(y) = kappa r_en^3 / (2 fxy e^{3y}).
            log_t0 = log_kappa + 3.0 * (m.lxy[j] - m.lxy0[j]) + 3.0 * math.log(p.r_en) - np.log(2.0 * m.fxy[j])
            gamma = _gamma(log_r[j], m.log_gxy[j], m.fxy[j], p.r_en)
            sj = _at(sigma, j)
            ae, be = a[exact], b[exact]
            nar = self.regimes.narrow
            nar = np.zeros(j.shape, bool) if nar is None else nar[j]
            pe = np.empty(j.shape)
            if nar.any():  # P(a < log dxy <= b) = P(log_t0 - 3b <= log|h| + 3 sigma Z < log_t0 - 3a)
                sn = _at(sj, nar)
                pe[nar] = smoothed_ball_disk_bin(log_t0[nar] - 1.5 * (ae[nar] + be[nar]), 3.0 * (be[nar] - ae[nar]), gamma[nar], 3.0 * sn)
            wide = ~nar
            if wide.any() and grad:  # (nar is empty: exact poses)
                ca, cb = _cdf_at(log_t0, ae, gamma, sj, True), _cdf_above(log_t0, be, gamma, sj, True)
                diff = ca[0] - cb[0]
                pe = np.maximum(diff, 0.0)
                d_lt, d_lg, d_s3 = (ca[i] - cb[i] for i in (1, 2, 3))
                # log t0 = log kappa + 3 log r_en + ..., log gamma = 3 log r_en + ..., s3 = 3 sigma
                dpe = np.stack([d_lt, 3.0 * (d_lt + d_lg), (3.0 * sj) * d_s3])
                dpm[:, exact] = np.where(diff > 0.0, dpe, 0.0)
            elif wide.any():
                sw = _at(sj, wide)
                lw, gw = log_t0[wide], gamma[wide]
                pe[wide] = np.maximum(_cdf_at(lw, ae[wide], gw, sw) - _cdf_above(lw, be[wide], gw, sw), 0.0)
            pm[exact] = pe
        return (pm, dpm) if grad else pm

    # -- diagnostics ------------------------------------------------------------------
    def prob_below(self, p: Params) -> NDArray[np.float64]:
        """P(outcome < observed) per row, outcomes ordered 0 < 1 < ... < r_outer < -1
        (-1 last: "farther than shown"); with :meth:`prob`, gives randomised PIT values."""
        k = self.k
        below = np.where(k == -1, 1.0, 0.0)
        det = k >= 1
        if det.any():
            widened = _UnionBin(self, det)
            below[det] = mixed(p, widened.prob_le) * (1.0 - p.dropout)
        cens = k == -1
        if cens.any():
            below[cens] = 1.0 - self.prob_censored(p)[cens]
        return np.clip(below, 0.0, 1.0)

    def prob_censored(self, p: Params) -> NDArray[np.float64]:
        """P(d = -1) for every row, whatever was observed."""
        saved = self.k, self.censored
        try:
            self.k = np.full_like(saved[0], -1)
            self.censored = np.ones_like(saved[1])
            return (1.0 - p.dropout) * self.prob(p) + p.dropout
        finally:
            self.k, self.censored = saved


def mixed(p: Params, f):
    """f(p), or with heavy-tailed GPS error (p.gps_outlier = w > 0) the mixture
    (1 - w) f(usual) + w f(wide) of its components (:meth:`Params.outlier_components`):
    a row's horizontal GPS error is from the wide one with probability w. The pose-error
    moments are linear in each group's sigma^2, so the wide component is the same rows'
    moments at a larger horizontal sigma."""
    if not p.gps_outlier > 0.0:
        return f(p)
    usual, wide = p.outlier_components()
    return (1.0 - p.gps_outlier) * f(usual) + p.gps_outlier * f(wide)


@dataclass
class _Mid:
    """Per-row quantities :meth:`Likelihood.mid_prob` needs, computed once per evaluation."""

    geo: Geometry
    log_gxy: NDArray[np.float64]
    lxy: NDArray[np.float64]  # log dxy without noise
    fxy: NDArray[np.float64]  # noise radius along the signal / max q
    log_kappa: float
    sigma: float | NDArray[np.float64]  # one per row with the errors-in-variables model
    params: Params
    lxy0: NDArray[np.float64]  # lxy before the pose-error shift


class _UnionBin:
    """P(d < k) for detected rows: all inner outcomes below k, plus mid ones below k."""

    def __init__(self, like: Likelihood, rows: NDArray[np.bool_]) -> None:
        self.like = like
        self.rows = rows

    def prob_le(self, p: Params) -> NDArray[np.float64]:
        like = self.like
        geo = like.geometry(p)
        sel = self.rows
        k = like.k[sel].astype(np.float64)
        y = np.log((k - 0.5) / 100.0)  # d < k <=> distance < (k - 0.5) cm
        log_r = geo.log_r[sel]
        g = geo.g[:, sel]
        gx, gy, gz = g
        with np.errstate(divide="ignore"):
            log_gxy = np.log(np.hypot(gx, gy))
        log_g3 = 0.5 * np.log(gx * gx + gy * gy + gz * gz)
        fxy, f3 = _qfactors(g, p.q)
        lk = math.log(p.kappa_eq)
        l3 = log_r + (lk - log_g3) / 3.0
        lxy = log_r + (lk - log_gxy) / 3.0
        e3 = np.exp(_log_eps(log_r, log_g3, f3, p.r_en)) / 3.0
        log_in, log_out = math.log(p.r_inner), math.log(p.r_outer)
        lxy0 = lxy
        sigma, sig3, l3, lxy = like.pose_spread(p, l3, lxy, sel)
        p_in_below = epan_gauss_cdf(np.minimum(y, log_in) - l3, e3, sig3)
        p_not_inner = 1.0 - epan_gauss_cdf(log_in - l3, e3, sig3)
        top = np.minimum(y, log_out)
        exact = like.regimes.exact[sel]
        pm = np.zeros(k.shape[0])
        s = ~exact & (top > log_in)
        if s.any():
            exy = np.exp(_log_eps(log_r[s], log_gxy[s], fxy[s], p.r_en)) / 3.0
            pm[s] = epan_gauss_interval(log_in - lxy[s], top[s] - lxy[s], exy, _at(sigma, s))
        x = exact & (top > log_in)
        if x.any():
            log_t0 = lk + 3.0 * (lxy[x] - lxy0[x]) + 3.0 * math.log(p.r_en) - np.log(2.0 * fxy[x])
            gamma = _gamma(log_r[x], log_gxy[x], fxy[x], p.r_en)
            sx = _at(sigma, x)
            pm[x] = _cdf_at(log_t0, np.full(gamma.shape, log_in), gamma, sx) - _cdf_at(log_t0, top[x], gamma, sx)
        return p_in_below + p_not_inner * np.maximum(pm, 0.0)


def _at(s, idx):
    """s[idx] for a per-row sigma, s itself for a scalar one."""
    return s if np.ndim(s) == 0 else s[idx]


def _gamma(log_r, log_gxy, fxy, r_en):
    """Signal / noise radius in the xy plane, |c_xy| / b (0 when g_xy = 0)."""
    with np.errstate(over="ignore"):
        return np.minimum(np.exp(-_log_eps(log_r, log_gxy, fxy, r_en)), 1e300)


def _cdf_grad(w, dw_dx, e, s) -> NDArray[np.float64]:
    """Derivatives of F(w; e, s) (:func:`special.epan_gauss_cdf`, s a scalar) in (log kappa,
    log r_en, log s), w moving by ``dw_dx`` per unit log kappa, e as r_en^-3 (module
    docstring); 0 at w = +-inf. Shape (3, len(w))."""
    return _cdf_grad_of(w, dw_dx, s, *epan_gauss_density(w, e, s))


def _cdf_grad_of(w, dw_dx, s, f, df) -> NDArray[np.float64]:
    """:func:`_cdf_grad` from F's u-derivatives (f, f') at w."""
    fin = np.isfinite(w)
    ww = np.where(fin, w, 0.0)
    s2df = (s * s) * df
    return np.stack([f * dw_dx, 3.0 * (ww * f + s2df), s2df])


def _interval_value_grad(a, b, e, s):
    """:func:`special.epan_gauss_interval` (a, b = bound - l, l moving by 1/3 per unit log
    kappa; s a scalar) and its derivatives (:func:`_cdf_grad`; 0 where the value was
    clipped), taken from the same tails it takes the values from; each bound's CDF and
    density from the same partial moments (the value is epan_gauss_interval's, bit for bit)."""
    a, b, e = np.broadcast_arrays(*(np.asarray(v, float) for v in (a, b, e)))
    upper = (a + b) > 0
    lo = np.where(upper, -b, a)
    hi = np.where(upper, -a, b)
    dx = np.where(upper, -1.0, 1.0) * (-1.0 / 3.0)  # d(sgn (bound - l)) / dlog kappa
    c_hi, *fd_hi = epan_gauss_cdf(hi, e, s, density=True)
    c_lo, *fd_lo = epan_gauss_cdf(lo, e, s, density=True)
    value = np.maximum(c_hi - c_lo, 0.0)
    d = _cdf_grad_of(hi, dx, s, *fd_hi) - _cdf_grad_of(lo, dx, s, *fd_lo)
    return value, np.where(value > 0.0, d, 0.0)


def _cdf_at(log_t0, y, gamma, sigma, grad=False):
    """P(|h_xy| < rho(y)) = P(log dxy > y) with the pose error: G(t(y)), t = e^{log_t0 - 3y}
    (with ``grad``: and its derivatives in log t, log gamma and 3 sigma)."""
    with np.errstate(invalid="ignore"):
        lt = log_t0 - 3.0 * y
    lt = np.where(np.isnan(lt), -np.inf, lt)  # y = +inf: threshold 0
    # G = 1 beyond gamma + 1, and the pose error reaches 8 s.d. (3 sigma each) past it.
    lt = np.clip(lt, -745.0, np.log(gamma + 2.0) + 30.0 * sigma)
    return smoothed_ball_disk_cdf(lt, gamma, 3.0 * sigma, grad=grad)


def _cdf_above(log_t0, y, gamma, sigma, grad=False):
    """:func:`_cdf_at` at the upper bound ``y`` of a bin: +inf for the censored rows, where it
    is 0 (threshold 0, G = 0 exactly), so only the finite bounds are evaluated."""
    fin = np.isfinite(y)
    if fin.all():
        return _cdf_at(log_t0, y, gamma, sigma, grad)
    sub = np.flatnonzero(fin)
    sig = sigma if np.ndim(sigma) == 0 else sigma[sub]
    part = _cdf_at(log_t0[sub], y[sub], gamma[sub], sig, grad)
    if not grad:
        out = np.zeros(y.shape)
        out[sub] = part
        return out
    out = [np.zeros(y.shape) for _ in part]
    for o, v in zip(out, part):
        o[sub] = v
    return out


def simulate(geo: Geometry, p: Params, rng: np.random.Generator, spread=None) -> NDArray[np.int64]:
    """Draw outcomes d (cm, -1 outer) from the model for each row's geometry.

    The receiver of BRIEF 3 with ball noise (drawn in the receiver frame: R_r^T w is
    uniform in the ball whenever w is), and the pose error exp(sigma Z) on both distances
    (``spread``: per-row shift and s.d. of log d instead, the errors-in-variables model's:
    there the signal is scaled by exp(-3 x shift-and-spread) before the EMI is added).
    With pose_sigma = 0 it returns exactly what :func:`emulator.receiver.model.measure` returns for
    noise points u = R_r^T w (tested).
    """
    n = geo.log_r.shape[0]
    z = rng.standard_normal((n, 5))
    u = z[:, :3] / np.sqrt(np.einsum("ij,ij->i", z, z))[:, None]
    qn = np.asarray(p.q, dtype=float) / max(p.q)
    r = np.exp(geo.log_r)
    rho = 2.0 * (r / p.r_en) ** 3  # noise radius / signal scale, h * 4 pi r^3 = g + rho Q u
    sig = 1.0
    if spread is not None:  # errors-in-variables: per-row (shift, s.d.) of log d, from Likelihood.pose_spread;
        # the pose error moves the signal, the EMI stays (pose_error.signal_error_cdf)
        sig = np.exp(-3.0 * (spread[0] + spread[1] * rng.standard_normal(n)))
    hx = geo.g[0] * sig + rho * qn[0] * u[:, 0]
    hy = geo.g[1] * sig + rho * qn[1] * u[:, 1]
    hz = geo.g[2] * sig + rho * qn[2] * u[:, 2] if p.antennas == 3 else np.zeros(n)  # 2 antennas: no h_z
    jitter = np.exp(p.pose_sigma * rng.standard_normal(n)) if (spread is None and p.pose_sigma > 0) else 1.0
    scale = r * np.cbrt(p.kappa_eq) * jitter
    hxy = np.hypot(hx, hy)
    with np.errstate(divide="ignore"):
        d3 = scale / np.cbrt(np.sqrt(hxy * hxy + hz * hz))
        dxy = scale / np.cbrt(hxy)
    inner = d3 <= p.r_inner
    mid = ~inner & (hxy > 0) & (dxy <= p.r_outer)
    dist = np.where(inner, d3, dxy) * 100.0
    t = np.trunc(dist)
    k = (t + (dist - t >= 0.5)).astype(np.int64)
    shown = inner | mid
    if p.dropout > 0.0:  # (drawn only then: the outcomes of a model without it are unchanged)
        shown &= rng.random(n) >= p.dropout
    return np.where(shown, k, -1)
