"""Maximum-likelihood calibration of the receiver model: :func:`fit` (issues 6 and 28).

:func:`fit` validates a :class:`Table` (:func:`check_table`), builds the rows it uses
(:mod:`.eiv`: with pose error, the geometry at the expected true poses and each row's
pose-error moments, re-evaluated at the estimate in up to three passes), runs the search
(:mod:`.stages`: pilot, Newton passes of :mod:`.search`, for big tables a subsample and
then all rows), the standard errors (:mod:`.covariance`: the Hessian at the estimate and
the sandwich with a time-block meat), and with pose error the time-offset scan
(:mod:`.offset`), refitting with the offset free when the poses fit clearly better at
one. Units: kappa_eq for a transmitter moment s = 1, lengths in m, sigmas in m and rad,
times in s; the optimiser works on logs of the positive parameters (:mod:`.params`).
"""


from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from . import parallel
from .covariance import (
    FEW_WINDOWS, boundary_nuisance_cov, common_height_rows, expected_information, measurable, row_scores,
    score_height_slope, separable, time_block_meat, with_common_height,
)  # fmt: skip
from .diagnostics import goodness_of_fit
from .eiv import EIV_POSE_SIGMA, EIV_START, eiv_rows, rule_sigmas, usable
from .likelihood import FREE_PARAMS, LINEAR, Rows, from_params, rows_from_table, to_params
from .offset import OFFSET_GAIN, offset_scan
from .params import BOUNDS, MAY_VANISH, box
from .pilot import naive_fit
from .result import FitOptions, FitResult
from .stages import SUBSAMPLE, fit_r_outer, full_stage, run_stages
from .table import FitInputError, Table, check_times, gps_scale

MIN_ROWS = 50
#: 90 % of rows within this ratio of distances is "no spread".
MIN_SPREAD = 1.25


# -- input checks ---------------------------------------------------------------------


def check_table(table: Table, options: FitOptions) -> Rows:
    """The fit-level checks (BRIEF issue 6 item 4); returns the usable rows. Stamps that
    go backwards are refused here (:func:`table.check_times`)."""
    src = table.source
    n = len(table)
    if n == 0:
        raise FitInputError(f"{src}: no rows")
    if n < MIN_ROWS:
        raise FitInputError(f"{src}: only {n} row{'s' if n > 1 else ''}; the fit needs at least {MIN_ROWS}")
    check_times(table)
    detected = table.d != -1
    if not detected.any():
        raise FitInputError(f"{src}: all {n} rows are -1 (nothing was detected); walk closer to the transmitter")
    need_track = "time_offset" in options.free or options.base.time_offset != 0.0
    if need_track and np.unique(table.t).shape[0] < 4:
        raise FitInputError(f"{src}: time_offset needs at least 4 distinct times")
    rows = rows_from_table(table, with_track=need_track)
    r = rows.geo.r
    if not np.any(r > 0):
        raise FitInputError(f"{src}: every row has the receiver at the transmitter (distance 0)")
    lo, hi = np.percentile(r, [5, 95])
    if not hi > MIN_SPREAD * lo:
        raise FitInputError(
            f"{src}: no spread of distances: 90 % of rows lie between {lo:.2f} and {hi:.2f} m; "
            f"walk over a range (at least a factor {MIN_SPREAD:g})"
        )
    base = options.base
    if not (math.isfinite(base.gps_ratio) and base.gps_ratio > 0):
        # the vertical GPS error is gps_ratio * gps_sigma: 0 would divide the moments by zero
        raise FitInputError(f"{src}: gps_ratio (vertical / horizontal GPS error) must be > 0, got {base.gps_ratio!r}")
    if "r_outer" not in options.free:
        limit = 100.0 * base.r_outer + 0.5
        over = table.d > limit
        if over.any():
            k = int(np.argmax(over))
            raise FitInputError(
                f"{table.where(k)}: d = {table.d[k]} cm is beyond r_outer = {base.r_outer:g} m; "
                "pass --r-outer or --fit r_outer"
            )
    return rows



def fit(table: Table, options: FitOptions | None = None) -> FitResult:
    """Validate ``table`` and fit ``options.free`` (default :class:`FitOptions`: kappa_eq, r_en
    and the relative pose error; :data:`result.EIV_FREE` is what ``arva-bench fit`` fits);
    see the module docstring. Raises :class:`table.FitInputError` for a table it cannot
    use; a fit that does not converge says so in :attr:`FitResult.converged`.

    With the errors-in-variables model and the time offset neither fitted nor given, the
    fit then scans for one (:func:`offset_scan`) and, when the poses fit better at an
    offset by more than :data:`OFFSET_GAIN` nats, fits again with ``time_offset`` free;
    either way one note says what the scan found."""
    options = FitOptions() if options is None else options
    res = fit_once(table, options)
    eiv = res.params.gps_sigma > 0 or res.params.attitude_sigma > 0
    if not (options.scan_offset and eiv and res.converged and "time_offset" not in res.free and options.base.time_offset == 0.0):
        return res
    t0 = time.perf_counter()
    scan = offset_scan(table, res.params, options)
    res.seconds += time.perf_counter() - t0
    if scan is None:
        res.notes.append("time offset not checked: the poses have fewer than 4 distinct times")
        return res
    if scan.gain > OFFSET_GAIN:
        refit = fit_once(table, replace(options, free=res.free + ("time_offset",)))
        refit.notes.insert(
            0,
            f"time offset: on {scan.rows} rows the poses fit {scan.gain:.0f} nats better at t {scan.offset:+.2f} s "
            "than at t (a scan over +-3 s), so it was fitted; --time-offset SEC gives it instead",
        )
        refit.seconds += res.seconds  # the first fit and the scan
        refit.n_evals += res.n_evals
        return refit
    res.notes.append(
        f"time offset: none found (a scan over +-3 s on {scan.rows} rows: the best, t {scan.offset:+.2f} s, fits "
        f"{scan.gain:.1f} nats better than t, below {OFFSET_GAIN:g}); held at 0 s: --fit time_offset fits it anyway"
    )
    return res


def fit_once(table: Table, options: FitOptions) -> FitResult:
    """:func:`fit` without the time-offset scan."""
    t0 = time.perf_counter()
    for name in options.free:
        if name not in FREE_PARAMS:
            raise FitInputError(f"cannot fit {name!r}; choose from {', '.join(FREE_PARAMS)}")
    free = tuple(n for n in FREE_PARAMS if n in options.free)  # canonical order
    newton_free = tuple(n for n in free if n != "r_outer")
    base = options.base
    eiv = any(m in free for m in ("gps_sigma", "attitude_sigma", "height_offset")) or base.gps_sigma > 0 or base.attitude_sigma > 0
    all_rows = check_table(table, options)
    stamps = check_times(table)
    if eiv:
        if "pose_sigma" not in free and options.eiv_floor:
            base = replace(base, pose_sigma=EIV_POSE_SIGMA)
        if "gps_sigma" in free:
            base = replace(base, gps_sigma=EIV_START[0])
        if "attitude_sigma" in free:
            base = replace(base, attitude_sigma=EIV_START[1])
        all_rows.gps_scale = gps_scale(table)
        if len(table) >= parallel.WORKER_ROWS:
            parallel.get_worker()  # it starts (imports numpy) while this process prepares the rows
    notes: list[str] = [] if stamps.summary() is None else [stamps.summary()]
    if eiv and all_rows.gps_scale is not None:
        varied = float(np.ptp(all_rows.gps_scale[all_rows.gps_scale < 1e3])) if np.any(all_rows.gps_scale < 1e3) else 0.0
        notes.append(
            "each row's GPS error follows its logged fix quality and HDOP"
            + (" (gps_sigma is the median row's)" if varied > 0 else " (the same for every row)")
        )
    start = None
    prev = None
    n_evals = 0
    n_dropped = 0
    for eiv_pass in range(3 if eiv else 1):
        if eiv:
            at_p = base if start is None else start
            sigma0 = rule_sigmas(at_p, free)
            rows, n_dropped = eiv_rows(all_rows, table, sigma0, attitude=at_p.attitude_sigma)
            if rows.k.shape[0] < MIN_ROWS or not np.any(rows.k != -1):
                raise FitInputError(
                    f"{table.source}: only {rows.k.shape[0]} rows are farther from the transmitter than the "
                    "pose error; give --gps-sigma / --attitude-sigma if the poses are better than that"
                )
        else:
            rows = usable(all_rows)
        if "r_outer" in free:  # start just above the largest d shown
            base = replace(base, r_outer=max(base.r_outer, (int(np.max(rows.k)) + 0.5) / 100.0))
        naive = naive_fit(rows, base.r_inner)
        n = rows.k.shape[0]

        # Between errors-in-variables passes only the sigmas matter: the subsample's
        # estimate is enough, and all rows are fitted once, in the last pass.
        searching = eiv and "r_outer" not in free
        like, res, extra = run_stages(rows, base, newton_free, options, notes, start, not searching, prev)
        n_evals += extra
        r_outer_se = float("nan")
        if "r_outer" in free and res.ok:
            params = to_params(base, newton_free, res.theta)
            like.choose_regimes(params)
            r_outer, r_outer_se, _f = fit_r_outer(like, params, rows)
            base = replace(base, r_outer=r_outer)
            start = to_params(base, newton_free, res.theta)
            like, res, extra = run_stages(rows, base, newton_free, options, notes, start)
            n_evals += extra
        if not eiv or not res.ok:
            break
        start, prev = to_params(base, newton_free, res.theta), res
        new0 = rule_sigmas(start, free)
        if eiv_pass == 2 or all(abs(math.log(a / b)) < math.log(1.25) for a, b in zip(new0, sigma0)):
            if searching and rows.k.shape[0] > SUBSAMPLE and "time_offset" not in newton_free:
                like, res, extra = full_stage(rows, base, newton_free, options, notes, res)
                n_evals += extra
            break
    if eiv and n_dropped:
        notes.append(
            f"{n_dropped} rows left out: closer to the transmitter than the pose error lets the model place them"
        )
        if n_dropped > rows.k.shape[0]:
            notes.append(
                f"most rows ({n_dropped} of {n_dropped + rows.k.shape[0]}) were too close to the transmitter for the "
                "pose error: the estimates rest on the few others, and on emulated walks like this their intervals "
                "missed the truth (docs/accuracy.md (b)); walk farther out, or log with a better GPS"
            )
    theta_n, fval, hess, active, ok, why = res.theta, res.f, res.hess, res.active, res.ok, res.why
    lo_n, hi_n = box(newton_free)
    if active is not None:
        # A pose-error sigma within 2 % of its lower bound sits in a flat valley (its effect
        # is lost in the rounding): hold it there, or its near-zero curvature would make
        # every other standard error huge.
        vanish = np.array([m in MAY_VANISH for m in newton_free]) & (theta_n <= lo_n + math.log(1.02))
        active = active | vanish | (theta_n >= hi_n - 1e-6)  # r_en a hair below its ceiling
    theta_n = np.where(active & (theta_n <= lo_n + math.log(1.02)), lo_n, theta_n)  # exactly at the bound
    params = to_params(base, newton_free, theta_n)
    for name in MAY_VANISH:
        if name in newton_free and active[newton_free.index(name)] and theta_n[newton_free.index(name)] <= lo_n[newton_free.index(name)] + 1e-6:
            params = replace(params, **{name: BOUNDS[name][0]})
    theta = from_params(params, free)

    estimate = {m: (float(theta[i]) if m in LINEAR else math.exp(theta[i])) for i, m in enumerate(free)}
    for name in MAY_VANISH:
        if name in free:
            estimate[name] = getattr(params, name)
    se_model = {m: float("nan") for m in free}
    nuisance_floor: list[str] = []  # sigmas at their floor whose uncertainty the s.e. include
    hac_lag = float("nan")
    cov = np.full((len(free), len(free)), np.nan)
    se = {m: float("nan") for m in free}
    ix = [free.index(m) for m in newton_free]
    lo, _hi = box(newton_free)
    if ok and hess is not None:
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
            if options.covariance == "hac" and eiv and like.rows.t is not None:
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
                    meat, hac_lag = time_block_meat(*with_common_height(scores, like.rows.t, height, slope))
                    sub_cov = model_cov @ meat @ model_cov
            for a_, i in enumerate(keep):
                name = newton_free[i]
                sd = math.sqrt(max(model_cov[a_, a_], 0.0))
                se_model[name] = sd if name in LINEAR else estimate[name] * sd
                for b_, j in enumerate(keep):
                    cov[ix[i], ix[j]] = sub_cov[a_, b_]
        except np.linalg.LinAlgError:
            ok = False
            why = "the likelihood has no curvature in some direction: a parameter cannot be estimated from these rows"
        if hac_lag == hac_lag:
            span = float(np.ptp(like.rows.t)) + 1.0  # s of receiver time the meat saw
            if span < FEW_WINDOWS * hac_lag:
                notes.append(
                    f"the time-block standard errors rest on {span:.0f} s of data, {span / hac_lag:.1f} times their "
                    f"{hac_lag:.0f} s bandwidth: with fewer than {FEW_WINDOWS} they run short (docs/accuracy.md (b)); "
                    "log longer before trusting the interval"
                )
        for i in keep:
            name = newton_free[i]
            sd = math.sqrt(max(cov[ix[i], ix[i]], 0.0))
            se[name] = sd if name in LINEAR else estimate[name] * sd  # delta method
        for i in np.flatnonzero(active):
            name = newton_free[i]
            at_lower = theta_n[i] <= lo[i] + 1e-6
            if name in MAY_VANISH and at_lower:
                what = {"pose_sigma": "the poses look exact", "gps_sigma": "no GPS error is visible"}.get(
                    name, "no attitude error is visible"
                )
                held_how = (
                    "the other standard errors include how far it could be above it (its variance is a "
                    "nuisance parameter there)"
                    if name in nuisance_floor
                    else "the other standard errors hold it there"
                )
                notes.append(f"{name} is at its lower bound {BOUNDS[name][0]:g} ({what}); {held_how}")
            else:
                ok = False
                bound = BOUNDS[name][0 if at_lower else 1]
                hint = " (the data show no noise floor)" if name == "r_en" and not at_lower else ""
                why = f"{name} runs to its {'lower' if at_lower else 'upper'} bound {bound:g}{hint}"
    for name in ("kappa_eq", "r_en"):
        if ok and name in free and se[name] > 0.5 * estimate[name]:
            notes.append(
                f"{name} is poorly determined (standard error {se[name]:.3g} against {estimate[name]:.4g}); "
                "check time alignment and the pose error"
            )
    if "r_outer" in free:
        se["r_outer"] = r_outer_se
        j = free.index("r_outer")
        cov[j, j] = (r_outer_se / estimate["r_outer"]) ** 2
        notes.append("r_outer is an end point: its standard error is a likelihood-ratio interval width / 3.92")
    told_apart = separable(ok, why, free, cov, estimate, se)
    if not told_apart:
        ok_line = (
            "pose error and EMI noise cannot be told apart with these rows "
            f"(no readings closer than {math.exp(float(np.percentile(rows.geo.log_r, 2))):.1f} m to the transmitter): "
            "r_en is not determined; walk closer or give --gps-sigma / --attitude-sigma"
        )
        notes.insert(0, ok_line)
    gof = goodness_of_fit(rows, params, options.seed) if ok else None
    if gof is not None and gof.note() is not None:
        notes.append(gof.note())
    info = None
    if ok and options.expected_se:
        info = expected_information(like, base, newton_free, theta_n, options.seed)
    return FitResult(
        source=table.source,
        params=params,
        free=free,
        estimate=estimate,
        se=se,
        cov_theta=cov,
        log_likelihood=-fval,
        n_rows=len(table),
        n_censored=int(np.sum(table.d == -1)),
        n_used=n,
        converged=ok,
        message=why,
        iterations=res.iterations,
        n_evals=n_evals,
        seconds=time.perf_counter() - t0,
        naive=naive,
        exact_fraction=float(np.mean(like.regimes.exact)) if like.regimes is not None else float("nan"),
        notes=notes,
        expected_information=info,
        se_model=se_model,
        hac_lag=hac_lag,
        separable=told_apart,
        n_pose_dropped=n_dropped,
        stamps=stamps,
        goodness_of_fit=gof,
        n_evals_all_rows=res.full_evals or (n_evals if n <= SUBSAMPLE or "time_offset" in newton_free else 0),
    )



#: The name callers used before :func:`fit` (the same function).
fit_table = fit
