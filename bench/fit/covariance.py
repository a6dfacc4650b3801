"""Standard errors: the observed information, the sandwich with a time-block meat, and
the terms the fit adds to it.

Per-row scores by central differences (:func:`row_scores`), the Newey-West meat over
seconds of receiver time (:func:`time_block_meat`), the common height's influence
(:func:`common_height_rows`, :func:`score_height_slope`), pose-error variances at their
floor as nuisance parameters (:func:`boundary_nuisance_cov`), and which Hessian blocks
can be inverted (:func:`measurable`). Everything on the optimiser's scale (logs of the
positive parameters; heights in m, times in s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from .likelihood import Likelihood, Params, Regimes, Rows, simulate, to_params
from .params import LINEAR, box
from .parallel import logps
from .pose_error import posterior_positions
from .table import Table

#: Fewer bandwidths of data than this under the time-block meat, and the fit says its
#: standard errors run short: the long-run variance is then estimated from a handful of
#: windows (10-minute campaigns, ~6 of them, covered 80-83 % of kappa_eq in
#: docs/accuracy.md (b); 30 minutes, ~11, 88-95 %). Measured before :func:`fixed_b_scale`,
#: which widens a 10-minute log's intervals by ~25 % and a 30-minute log's by ~14 %; not
#: measured since.
FEW_WINDOWS = 8


def row_scores(like: Likelihood, base: Params, free: tuple[str, ...], theta, h, live=None):
    """Per-row central-difference gradients of log P (N, p) (columns ``live`` only)."""
    cols = range(len(free)) if live is None else list(live)
    scores = np.empty((like.k.shape[0], len(cols)))
    points = []
    for j in cols:
        e = np.zeros(len(free))
        e[j] = h[j]
        points += [to_params(base, free, theta + e), to_params(base, free, theta - e)]
    outs = logps(like, points)
    for c, j in enumerate(cols):
        up, down = outs[2 * c], outs[2 * c + 1]
        scores[:, c] = (up - down) / (2.0 * h[j])
    return scores


def expected_information(like: Likelihood, base: Params, free: tuple[str, ...], theta, seed: int = 0, reps: int = 8):
    """E[sum_i s_i s_i^T] at theta, by simulating every row's outcome from the fitted model
    (:func:`likelihood.simulate`) ``reps`` times. Used by the coverage study in
    docs/calibration.md, not by the fit."""
    params = to_params(base, free, theta)
    geo = like.geometry(params)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xF1,)))
    h = np.array([0.01 if n == "time_offset" else 1e-4 for n in free])
    info = np.zeros((len(free), len(free)))
    for _ in range(reps):
        sim = Likelihood(Rows(simulate(geo, params, rng), like.rows.geo, like.rows.track), like.regimes)
        s = row_scores(sim, base, free, theta, h)
        info += s.T @ s
    return info / reps


#: is not positive definite along them, least identified first (:func:`measurable`).
UNMEASURABLE = ("attitude_sigma", "gps_sigma")


def measurable(hess: NDArray[np.float64], keep: NDArray[np.int64], free: tuple[str, ...]):
    """(keep, None) when the Hessian of the parameters ``keep`` is positive definite; else
    (keep without one pose-error sigma, its name) when that makes it so. A sigma that the
    data barely identify (attitude error on a 4-hour walk: anywhere from its floor to
    5 deg at 2 deg true) can leave a Hessian by differences with a negative eigenvalue
    along it a little above its floor, where the likelihood is flat: 4 of 200 seeded
    4-hour campaigns failed with "no curvature" for that alone. Otherwise (keep, None),
    and the caller's Cholesky says the fit has no curvature, as before."""

    def positive(idx) -> bool:
        try:
            np.linalg.cholesky(hess[np.ix_(idx, idx)])
        except np.linalg.LinAlgError:
            return False
        return True

    if positive(keep):
        return keep, None
    for name in UNMEASURABLE:
        if name in free and free.index(name) in keep:
            trial = keep[keep != free.index(name)]
            if trial.size and positive(trial):
                return trial, name
    return keep, None


def boundary_nuisance_cov(like, base, free, theta, h, keep, floor, hess_keep, scores_keep, height=None):
    """The sandwich covariance of the ``keep`` parameters when pose-error sigmas (indices
    ``floor``) sit at their lower bound: their variances v = sigma^2 join as nuisance
    parameters instead of being held fixed.

    At the floor the likelihood is flat in log sigma (it depends on sigma through
    sigma^2), so the log-scale Hessian has no information about it; in v it has. A sigma
    held there as known made the others' standard errors too small: on emulated
    60-minute campaigns with 2 deg attitude error, attitude_sigma went to its floor in
    about one seed in four and those seeds' kappa_eq errors were up to 2.2 of their
    standard errors (docs/accuracy.md (b)). Here the Hessian and the per-row scores are
    extended by one-sided differences in v (steps about half a standard error of v, from
    v at the floor upwards; second-order forward rules), the time-block meat is taken
    over all of them, and the ``keep`` block of A^-1 B A^-1 is returned with the
    inverse-Hessian block and the Newey-West lag, or None when the likelihood is not
    curved upwards in v (then the caller holds the sigmas as before). ``height``
    (:func:`common_height_rows`) adds the common height's influence to the meat.
    """
    keep = list(keep)
    m = len(floor)
    batch = lambda ths: logps(like, [to_params(base, free, th) for th in ths])  # noqa: E731 (one batch: :func:`logps`)
    v0 = np.exp(2.0 * theta[floor])

    def at(th, dv):  # theta with the floor sigmas at sqrt(v0 + dv)
        out = th.copy()
        out[floor] = 0.5 * np.log(v0 + dv)
        return out

    start = {"gps_sigma": 0.5**2, "attitude_sigma": math.radians(1.0) ** 2}
    delta = np.array([0.25 * start[free[i]] for i in floor])
    for _attempt in range(2):
        pairs = [(a, b) for a in range(m) for b in range(a + 1, m)]
        got = batch([theta] + [at(theta, delta * np.eye(m)[a]) for a in range(m)]
                    + [at(theta, 2.0 * delta * np.eye(m)[a]) for a in range(m)]
                    + [at(theta, delta * (np.eye(m)[a] + np.eye(m)[b])) for a, b in pairs])  # fmt: skip
        l00, one, two, both = got[0], got[1 : 1 + m], got[1 + m : 1 + 2 * m], dict(zip(pairs, got[1 + 2 * m :]))
        a_vv = np.empty((m, m))
        for a in range(m):
            a_vv[a, a] = -float(np.sum(two[a] - 2.0 * one[a] + l00)) / delta[a] ** 2
            for b in range(a + 1, m):
                a_vv[a, b] = a_vv[b, a] = -float(np.sum(both[a, b] - one[a] - one[b] + l00)) / (delta[a] * delta[b])
        if not np.all(np.diag(a_vv) > 0):
            return None
        se_v = 1.0 / np.sqrt(np.diag(a_vv))
        new = np.clip(0.5 * se_v, delta / 100.0, delta * 100.0)
        if _attempt == 0 and np.all(np.abs(np.log(new / delta)) < math.log(2.0)):
            break
        delta = new
    # Mixed terms theta_j (log scale, central) x v_a (forward).
    a_tv = np.empty((len(keep), m))
    shifts = []
    for j in keep:
        e = np.zeros_like(theta)
        e[j] = h[j]
        for a in range(m):
            dv = delta * np.eye(m)[a]
            shifts += [at(theta + e, dv), at(theta - e, dv), theta + e, theta - e]
    got = iter(batch(shifts))
    for c, j in enumerate(keep):
        for a in range(m):
            pv, mv, p0, m0 = next(got), next(got), next(got), next(got)
            val = pv - mv - p0 + m0
            a_tv[c, a] = -float(np.sum(val)) / (2.0 * h[j] * delta[a])
    big = np.block([[hess_keep, a_tv], [a_tv.T, a_vv]])
    try:
        np.linalg.cholesky(big)
    except np.linalg.LinAlgError:
        return None
    # Per-row scores in v at the floor: (-3 l(0) + 4 l(d) - l(2d)) / 2d.
    s_v = np.stack([(-3.0 * l00 + 4.0 * one[a] - two[a]) / (2.0 * delta[a]) for a in range(m)], axis=1)
    scores = np.concatenate([scores_keep, s_v], axis=1)
    slope = None
    if height is not None:  # d/d(height) of the summed scores: the kept columns, then the v columns
        sample = sub, idx, scale = height_sample(like)
        up = replace(base, height_offset=base.height_offset + HEIGHT_STEP)
        steps = [delta * np.eye(m)[a] for a in range(m)]
        got = logps(sub, [to_params(up, free, th) for th in [theta] + [at(theta, d) for d in steps] + [at(theta, 2.0 * d) for d in steps]])
        l0, l1, l2 = got[0], got[1 : 1 + m], got[1 + m :]
        s_v_up = np.array([float(np.sum(-3.0 * l0 + 4.0 * l1[a] - l2[a])) / (2.0 * delta[a]) for a in range(m)])
        slope = np.concatenate([score_height_slope(like, base, free, theta, h, keep, scores_keep, sample),
                                scale * (s_v_up - s_v[idx].sum(axis=0)) / HEIGHT_STEP])
    inv = np.linalg.inv(big)
    meat, lag = sandwich_meat(scores, like.rows.t, height, slope)
    cov = inv @ meat @ inv
    k = len(keep)
    return inv[:k, :k], cov[:k, :k], lag


#: The step in the common receiver height for :func:`score_height_slope` (m).
HEIGHT_STEP = 0.02


def common_height_rows(table: Table, sigma0) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Each logged row's share in the common height the fit placed the rows at, or None.

    :func:`pose_error.posterior_positions` moves each logged height z_i to
    m + k (z_i - m), m the mean logged height of all N rows of the table, so (1 - k)
    times the campaign mean of the vertical GPS error is in every row's height. With a
    flat walk k is ~0: the per-row vertical errors leave the scores, and what is left is
    common to all rows, which the time-block meat cannot see (it moves the estimate, not
    the scores). As for any two-step estimator (Newey and McFadden 1994, section 6) the
    first step's influence joins the scores: with the fit's scores S(theta, h), h a
    common height offset, the estimate moves by A^-1 (dS/dh) (1 - k) (m - E m), and
    (1 - k) (m - E m) is the sum over rows of w_i = (1 - k) (z_i - m) / N, a series
    correlated in time like the GPS error itself. Returns (w, t) per table row (t the
    receiver time) for :func:`with_common_height`; None when no vertical error is
    modelled or k = 1 (the heights are kept as logged)."""
    if sigma0[1] <= 0.0:
        return None
    post = posterior_positions(table.rx_pos, table.tx_pos, sigma0[0], sigma0[1])
    keep = 1.0 - post.v_factor**2
    if keep <= 0.0:
        return None
    z = np.asarray(table.rx_pos, dtype=np.float64)[:, 2]
    return keep * (z - z.mean()) / z.shape[0], np.asarray(table.t, dtype=np.float64)


#: Above this many rows the common height's slope is summed over a fixed random
#: subsample of them, scaled up (it only sizes a term of a few % of the meat; two
#: likelihood evaluations per parameter on 1e5 rows cost ~1 s).
HEIGHT_ROWS = 10_000


def height_sample(like: Likelihood):
    """(likelihood, row index, scale) for the slope: all rows, or :data:`HEIGHT_ROWS` of
    them (seeded, sorted) with their frozen regimes, and N / n."""
    n = like.k.shape[0]
    if n <= HEIGHT_ROWS:
        return like, slice(None), 1.0
    idx = np.sort(np.random.default_rng(np.random.SeedSequence(n, spawn_key=(0x4E,))).choice(n, HEIGHT_ROWS, replace=False))
    reg = like.regimes
    if reg is not None:
        reg = Regimes(reg.exact[idx], reg.eps_split, None if reg.narrow is None else reg.narrow[idx])
    return Likelihood(like.rows.take(idx), reg), idx, n / HEIGHT_ROWS


def score_height_slope(like: Likelihood, base: Params, free, theta, h, cols, scores, sample=None) -> NDArray[np.float64]:
    """d/dh of the summed scores (columns ``cols``; ``scores`` their per-row values at
    h = 0), h a common offset of every receiver height (``Params.height_offset``,
    linearised), by a forward difference of :data:`HEIGHT_STEP` (two likelihood
    evaluations per column, on at most :data:`HEIGHT_ROWS` rows: the fit's last step,
    so kept cheap). ``sample``: :func:`height_sample`'s result, when the caller has it."""
    sub, idx, scale = height_sample(like) if sample is None else sample
    up = replace(base, height_offset=base.height_offset + HEIGHT_STEP)
    return scale * (row_scores(sub, up, free, theta, h, live=cols).sum(axis=0) - np.sum(scores[idx], axis=0)) / HEIGHT_STEP


def with_common_height(scores, t, height, slope):
    """The scores and times for :func:`time_block_meat`, with the common height's influence
    rows w_i (dS/dh) appended when ``height`` (:func:`common_height_rows`) is given."""
    if height is None or slope is None:
        return scores, t
    w, t_rows = height
    return np.concatenate([scores, np.outer(w, slope)]), np.concatenate([np.asarray(t, dtype=np.float64), t_rows])


def sandwich_meat(scores, t, height, slope) -> tuple[NDArray[np.float64], float]:
    """The sandwich's meat: :func:`time_block_meat` of the scores and times (the common
    height's rows appended: :func:`with_common_height`) times :func:`fixed_b_scale` for
    that bandwidth and those times; and the bandwidth (s)."""
    scores, t = with_common_height(scores, t, height, slope)
    meat, lag = time_block_meat(scores, t)
    return meat * fixed_b_scale(lag, t), lag


#: |correlation| of r_en with a pose-error sigma above which the two are not told apart.
SEPARATION_CORR = 0.9


def separable(ok, why, free, cov, estimate, se) -> bool:
    """Whether the fit told pose error from EMI noise: r_en determined to within half
    its value and not almost a function of a fitted pose-error sigma. Judged on converged
    fits only: a search that failed says why (r_en at its ceiling: no noise floor at
    all; a search that stopped), and blaming the pose error for it sent users to walk
    closer on walks that came within 2 m (issue 28)."""
    if "r_en" not in free:
        return True
    pose = [m for m in ("gps_sigma", "attitude_sigma") if m in free]
    if not pose:
        return True
    if not ok:
        return True
    i = free.index("r_en")
    for m in pose:
        j = free.index(m)
        if cov[i, i] > 0 and cov[j, j] > 0:
            if abs(cov[i, j]) / math.sqrt(cov[i, i] * cov[j, j]) > SEPARATION_CORR:
                return False
    return bool(se["r_en"] <= 0.5 * estimate["r_en"])


#: How far apart (s) :func:`time_block_meat` keeps two consecutive seconds that hold rows:
#: a longer gap is shortened to this.
MEAT_GAP = 3600


def seconds_axis(t: NDArray[np.float64]) -> NDArray[np.int64]:
    """Each row's second of receiver time from the first, as :func:`time_block_meat` sums
    them: seconds with nothing logged count (zeros in the sums), but a gap longer than
    :data:`MEAT_GAP` is shortened to it (it already separates its two sides beyond any
    bandwidth), so a log with a day's pause costs no day of zeros."""
    t = np.asarray(t, dtype=np.float64)
    sec = np.floor(t - t.min()).astype(np.int64)
    if int(sec.max()) > MEAT_GAP:
        seconds, at = np.unique(sec, return_inverse=True)
        sec = np.concatenate([[0], np.cumsum(np.minimum(np.diff(seconds), MEAT_GAP))])[at]
    return sec


def fixed_b_scale(lag: float, t: NDArray[np.float64]) -> float:
    """The factor on the sandwich's variances that makes estimate +- 1.96 s.e. a 95 %
    interval when the Newey-West bandwidth ``lag`` is a fraction b = lag / T of the T
    seconds (:func:`seconds_axis`) it was estimated from: (c(b) / 1.96)^2, c(b) = 1.96 +
    2.9694 b + 0.4160 b^2 - 0.5324 b^3, the 97.5 % point of the Bartlett kernel's fixed-b
    t statistic (Kiefer and Vogelsang 2005, Econometric Theory 21, their cubic fit).

    Why: with b not small (60 minutes: 240 / 3600) the long-run variance is estimated
    from a few windows, so it is noisy and, with the Bartlett weights, low; the t statistic
    is then wider than normal. Simulated white scores (T = 3600, L = 240, 6,000 series)
    covered 92.8 % at 1.96 and 95.2 % at c(b); white plus Gauss-Markov (tau 30 s) parts
    90.7-91.4 % and 93.2-94.2 % (``tests/perf/fixed_b_check.py``; docs/calibration.md,
    section 5). (b counts the L lags, not the L + 1 of the Bartlett window: < 0.1 % here.)
    Written here: statsmodels' HAC covariance (our meat's test oracle) has no fixed-b
    critical values (searched in the installed 0.15.0 sources, 2026-12-05)."""
    b = min(lag / (int(seconds_axis(t).max()) + 1.0), 1.0)
    return ((1.96 + 2.9694 * b + 0.4160 * b * b - 0.5324 * b**3) / 1.96) ** 2


def time_block_meat(scores: NDArray[np.float64], t: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """The meat of the sandwich covariance, robust to scores correlated in time.

    Scores (N, p) are summed per second of receiver time (several rows per second add up;
    gaps are zeros), then the long-run covariance of that series is the Newey-West
    estimate with Bartlett weights 1 - l/(L + 1), l = 1..L. L is Andrews' (1991) AR(1)
    plug-in, L = 1.1447 (alpha T)^(1/3), but at least 4 sqrt(T) and at most T/4: the
    scores are mostly white EMI noise with a small pose-error part correlated over tens
    of seconds, and the AR(1) fit to their sum sees only the white part (it chose ~25 s
    on 30 s Gauss-Markov GPS error, and the intervals were too short). Returns (meat, L).
    """
    sec = seconds_axis(t)
    T = int(sec.max()) + 1
    p = scores.shape[1]
    x = np.zeros((T, p))
    for j in range(p):
        x[:, j] = np.bincount(sec, weights=scores[:, j], minlength=T)
    x -= x.mean(axis=0)
    num = den = 0.0
    for j in range(p):
        a, b = x[1:, j], x[:-1, j]
        bb = float(b @ b)
        if bb <= 0:
            continue
        rho = float(np.clip((a @ b) / bb, -0.99, 0.99))
        s2 = float(np.mean((a - rho * b) ** 2))
        num += 4.0 * rho * rho * s2 * s2 / ((1.0 - rho) ** 6 * (1.0 + rho) ** 2)
        den += s2 * s2 / (1.0 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    lag = min(max(1.1447 * (alpha * T) ** (1.0 / 3.0), 4.0 * math.sqrt(T)), T / 4.0)
    big_l = int(math.floor(lag))
    # sum_l (1 - |l|/(L + 1)) Gamma_l = sum_m S_m S_m^T / (L + 1), S_m the sums of x over the
    # windows [m, m + L] (x zero outside [0, T)): each pair (t, s) lies in L + 1 - |t - s|
    # windows. O(T p^2) instead of O(T L p^2).
    cs = np.concatenate([np.zeros((1, p)), np.cumsum(np.concatenate([x, np.zeros((big_l, p))]), axis=0)])
    windows = cs[1:] - np.concatenate([np.zeros((big_l, p)), cs[:T]])  # m = -L .. T - 1
    meat = windows.T @ windows / (big_l + 1.0)
    return meat, float(lag)


@dataclass
class Uncertainty:
    """The standard errors of a fit (:func:`standard_errors`): ``se`` in natural units (the
    delta method from the optimiser's scale), ``se_model`` the inverse Hessian's (rows
    independent), ``cov`` the sandwich on the optimiser's scale (all free parameters, NaN
    where none), the Newey-West bandwidth (s), the pose-error sigmas at their floor whose
    variance is a nuisance parameter, the notes to add, and why there are none (no
    curvature) or None."""

    se: dict[str, float]
    se_model: dict[str, float]
    cov: NDArray[np.float64]
    hac_lag: float
    nuisance_floor: list[str]
    notes: list[str]
    failed: str | None


def standard_errors(like, res, base, free, newton_free, theta_n, active, estimate, covariance, eiv, table, sigma0) -> Uncertainty:
    """The standard errors at the estimate ``theta_n`` of the search ``res`` (a converged
    :class:`search.NewtonResult` whose Hessian is of the ``newton_free`` parameters; those
    ``active`` are held at a bound): the inverse Hessian of the parameters whose curvature
    can be measured (:func:`measurable`); with the errors-in-variables model (``eiv``) and
    ``covariance`` "hac", the sandwich with the time-block meat of the per-row scores (the
    common height's influence added, :func:`common_height_rows`; pose-error sigmas at
    their floor as nuisance variances, :func:`boundary_nuisance_cov`). ``estimate``: the
    natural-unit estimates (for the delta method); ``sigma0``: the rule's sigmas of the
    last pass."""
    se_model = {m: float("nan") for m in free}
    nuisance_floor: list[str] = []  # sigmas at their floor whose uncertainty the s.e. include
    hac_lag = float("nan")
    cov = np.full((len(free), len(free)), np.nan)
    se = {m: float("nan") for m in free}
    ix = [free.index(m) for m in newton_free]
    lo_n, _hi = box(newton_free)
    notes: list[str] = []
    failed = None
    hess = res.hess
    if res.ok and hess is not None:
        keep, unmeasured = measurable(hess, np.flatnonzero(~active), newton_free)
        if unmeasured is not None:
            notes.append(
                f"{unmeasured}'s curvature could not be measured (the likelihood is flat or uneven along it at the "
                "estimate): it is held at its estimate for the other standard errors, which leave out its uncertainty"
            )
        try:
            hk = hess[np.ix_(keep, keep)]
            np.linalg.cholesky(hk)
            model_cov = np.linalg.inv(hk)
            sub_cov = model_cov
            if covariance == "hac" and eiv and like.rows.t is not None:
                # at the last gradient's point (its per-row log P are memoised) when the
                # estimate is an unevaluated Newton step from there (full_stage, < 0.08
                # standard errors): the meat is centred (kappa_eq's and r_en's s.e. moved
                # by < 0.2 % on the 1e5-row pose-error benchmark's campaigns); so are the
                # differences of boundary_nuisance_cov (its points at theta +- h: memoised)
                at = res.evaluated
                at = at if at is not None and np.array_equal(at[active], theta_n[active]) else theta_n
                scores = row_scores(like, base, newton_free, at, res.steps, live=keep)
                height = None if "height_offset" in newton_free else common_height_rows(table, sigma0)
                floor = [i for i in np.flatnonzero(active) if newton_free[i] in ("gps_sigma", "attitude_sigma")
                         and theta_n[i] <= lo_n[i] + 1e-6]  # fmt: skip
                widened = None
                if floor:
                    widened = boundary_nuisance_cov(like, base, newton_free, at, res.steps, keep, floor, hk, scores, height)
                if widened is not None:
                    model_cov, sub_cov, hac_lag = widened
                    nuisance_floor = [newton_free[i] for i in floor]
                else:
                    slope = None if height is None else score_height_slope(like, base, newton_free, at, res.steps, keep, scores)
                    meat, hac_lag = sandwich_meat(scores, like.rows.t, height, slope)
                    sub_cov = model_cov @ meat @ model_cov
            for a_, i in enumerate(keep):
                name = newton_free[i]
                sd = math.sqrt(max(model_cov[a_, a_], 0.0))
                se_model[name] = sd if name in LINEAR else estimate[name] * sd
                for b_, j in enumerate(keep):
                    cov[ix[i], ix[j]] = sub_cov[a_, b_]
        except np.linalg.LinAlgError:
            failed = "the likelihood has no curvature in some direction: a parameter cannot be estimated from these rows"
        if hac_lag == hac_lag:
            span = float(np.ptp(like.rows.t)) + 1.0  # s of receiver time the meat saw
            if span < FEW_WINDOWS * hac_lag:
                notes.append(
                    f"the time-block standard errors rest on {span:.0f} s of data, {span / hac_lag:.1f} times their "
                    f"{hac_lag:.0f} s bandwidth: with fewer than {FEW_WINDOWS} they ran short before the "
                    "fixed-b scale and are not measured since (docs/accuracy.md (b)); log longer before "
                    "trusting the interval"
                )
        for i in keep:
            name = newton_free[i]
            sd = math.sqrt(max(cov[ix[i], ix[i]], 0.0))
            se[name] = sd if name in LINEAR else estimate[name] * sd  # delta method
    return Uncertainty(se, se_model, cov, hac_lag, nuisance_floor, notes, failed)
