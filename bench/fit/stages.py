"""The search's stages: pilot, Newton passes with the likelihood regimes re-chosen, and
for big tables the subsample search followed by steps and the Hessian on all rows.

:func:`run_stages` runs them for one set of free parameters and returns the likelihood, the
:class:`search.NewtonResult` and the number of evaluations. Parameters on the optimiser's
scale (:mod:`.params`); tolerances are Newton decrements in nats.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from . import parallel  # (its STENCIL_THREADS read at each use: tests and benchmarks set it)
from .likelihood import BLOCK_ROWS, Likelihood, Params, Rows, from_params, mounted, to_params
from .offset import OFFSET_GRID
from .params import box
from .pilot import grid_values, median_kappa, pilot_sigma, vertex_shift
from .result import FitOptions
from .search import (
    DECREMENT_TOL, ONE_SIDED, Analytic, Differences, GradObjective, NewtonResult, Objective, Part, fd_gradient, merge, newton,
    outward,
)  # fmt: skip


def convex(res: "NewtonResult") -> bool:
    """Whether ``res`` has a Hessian worth starting quasi-Newton steps from (positive
    definite in its live parameters)."""
    if res.hess is None:
        return False
    live = np.flatnonzero(~res.active)
    w = np.linalg.eigvalsh(res.hess[np.ix_(live, live)]) if live.size else np.ones(1)
    return bool(np.all(np.isfinite(w)) and np.all(w > 0))


def still_held(like: Likelihood, base: Params, free, theta, h, prev: "NewtonResult") -> bool:
    """Whether every parameter ``prev`` held at a bound still has its gradient pointing
    out there (on ``like``, at ``theta``): quasi-Newton keeps them held, so a flat
    pose-error sigma the first pass pinned to its floor must be free to leave it (Newton
    re-checks the active set at each iteration). Two evaluations per held parameter."""
    held = prev.active
    if not held.any():
        return True
    f = Objective(like, base, free)
    lo, hi = box(free)
    g_held, _ = fd_gradient(Part(f, lambda th_h: merge(theta, held, th_h)), theta[held], h[held])
    g = np.zeros(len(free))
    g[held] = g_held
    return bool(np.all(outward(theta, g, lo, hi)[held]))


def quasi(like: Likelihood, base: Params, free, theta, options, h, tol, prev: "NewtonResult", forward=False) -> "NewtonResult":
    """Quasi-Newton (:func:`search.newton` by differences, BFGS) on ``like`` from ``prev``'s
    Hessian and bounds (``forward``: the steps' gradients by forward differences)."""
    h = prev.steps if h is None else h
    source = Differences(Objective(like, base, free), forward=forward)
    return newton(source, theta, free, options.max_iter, tol, h=h, held=prev.active, hess0=prev.hess, probe=False)


def optimise(rows: Rows, base: Params, free, theta, options, notes, h=None, tol=DECREMENT_TOL, warm=None, lead_in=False):
    """Newton with the S/L split re-chosen until the one at the estimate is the one the
    estimate was found with (the first pass stops early, at a decrement of 0.5 nats, the
    others at ``tol``; from a ``warm`` start, the previous pass's estimate, the first
    pass goes to ``tol`` too). A subsample's search (``tol`` SUB_TOL) stops
    after one full pass: all rows follow, with the split chosen at its estimate; it takes
    quasi-Newton steps from the previous pass's Hessian (``warm``: a :class:`NewtonResult` from
    rows linearised at other sigmas; else the 0.5-nat pass's). ``lead_in``: the search is
    only where the steps on all rows start (:func:`run_stages`): its quasi-Newton steps
    from ``warm`` take forward-difference gradients."""
    like = options.likelihood(rows)
    if rows.moments is not None:
        # quasi-Newton's final Hessian by differences re-visits the last gradient's axis
        # points (8 of its 20 with 4 parameters): kept, as on all rows (full_stage)
        like.remember = 4 * len(free) + 8
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    search = tol >= SUB_TOL
    if warm is not None and search and convex(warm):
        like.choose_regimes(to_params(base, free, theta), **eps_kw)
        if still_held(like, base, free, theta, warm.steps if h is None else h, warm):
            return like, quasi(like, base, free, theta, options, h, tol, warm, forward=lead_in)

    def one_pass(theta, settled, prev):
        steps = h if prev is None else prev.steps
        if settled and search and prev is not None and convex(prev) and still_held(like, base, free, theta, steps, prev):
            return quasi(like, base, free, theta, options, steps, tol, prev), True
        source = Differences(Objective(like, base, free))
        res = newton(source, theta, free, options.max_iter, tol if settled else 0.5, recompute=True, h=steps)
        return fallback(source, free, res, options, tol if settled else 0.5, recompute=True), False

    return like, regime_passes(like, base, free, theta, eps_kw, notes, search, warm is not None, one_pass)


#: The Newton failures :func:`fallback` takes over: the search stopped without meeting its
#: decrement (a flat valley, a sigma creeping to its floor, r_en to its ceiling), not a
#: likelihood that is zero or not finite.
STOPPED = ("no convergence after", "no step decreases")
#: The decrement (nats) at which the Newton search after scipy's stops: ~0.045 standard
#: errors from the optimum (as FINISH_TOL and the restart's estimate.RESTART_TOL).
FALLBACK_TOL = 1e-3


def fallback(source, free, res: "NewtonResult", options: FitOptions, tol: float, **newton_kw) -> "NewtonResult":
    """When Newton stopped (:data:`STOPPED`), scipy's L-BFGS-B with the BOUNDS box on the same
    objective from where it stopped (the gradient: ``source``'s, central differences with
    the search's steps or the analytic one), then Newton again from scipy's point (the
    same ``newton_kw``, at least :data:`FALLBACK_TOL`) for the active set, the Hessian and
    the convergence test. A bound that scipy reaches is held there by that search. Returns
    the new result when it converged, else ``res``. (Issue 28, item 4: far- and near-only
    walks stopped at "no convergence after 60 Newton iterations" or "no step decreases"
    in 8 of 100 report seeds, the restart of estimate.fit_restarted not mending them.)"""
    if res.ok or not res.why.startswith(STOPPED):
        return res
    from scipy.optimize import minimize

    lo, hi = box(free)
    p = len(free)
    everything = np.ones(p, bool)
    if source.scores:
        def fg(x):
            f0, g, _s = source.value(np.clip(x, lo, hi))
            return f0, g
    else:
        def fg(x):
            x = np.clip(x, lo, hi)
            f0 = source.value(x)[0]
            return f0, source.gradient(x, f0, everything, res.steps)[0]

    def safe(x):
        f0, g = fg(x)
        return (f0, g) if math.isfinite(f0) and np.all(np.isfinite(g)) else (1e300, np.zeros(p))

    try:
        out = minimize(safe, np.clip(res.theta, lo, hi), jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                       options={"maxiter": 200, "ftol": 1e-13, "gtol": 1e-7})  # fmt: skip
    except (ValueError, FloatingPointError):
        return res
    start = out.x if out.fun <= res.f else res.theta
    again = newton(source, start, free, options.max_iter, max(tol, FALLBACK_TOL), h=res.steps, **newton_kw)
    again.iterations += res.iterations + int(out.nit)
    return again if again.ok else res


def regime_passes(like: Likelihood, base: Params, free, theta, eps_kw: dict, notes: list[str], search: bool, settled0: bool, one_pass):
    """Up to four Newton searches, each with the likelihood regimes chosen at its start and
    frozen (so the objective stays smooth), until the regimes chosen at the estimate are
    the ones it was found with (:func:`regimes_settled`). The first pass (unless
    ``settled0``) only settles the regimes; a subsample's ``search`` stops after one
    settled pass. ``one_pass(theta, settled, previous result)`` runs one search and says
    whether it ends the loop at once (a quasi-Newton pass from the previous one's
    Hessian). Returns the last :class:`search.NewtonResult`, its iterations summed."""
    iters = 0
    res = None
    for _pass in range(4):
        like.choose_regimes(to_params(base, free, theta), **eps_kw)
        split = like.regimes.exact.copy()
        settled = _pass > 0 or settled0
        res, last = one_pass(theta, settled, res)
        if last:
            res.iterations += iters
            return res
        iters += res.iterations
        theta = res.theta
        if not res.ok or (settled and search):
            break
        if regimes_settled(like, to_params(base, free, theta), eps_kw, split, settled, notes):
            break
    res.iterations = iters
    return res


def regimes_settled(like: Likelihood, p: Params, eps_kw: dict, split, settled: bool, notes: list[str]) -> bool:
    """After a pass of the regime loop: the regimes chosen again at ``p``. True when the
    loop ends (a settled pass and no row changed: the pass's own split is kept); a row
    that changed after a settled pass is noted and the loop refits."""
    changed = int(np.sum(like.choose_regimes(p, **eps_kw).exact != split))
    if changed == 0 and settled:
        like.regimes.exact = split
        return True
    if changed and settled:
        notes.append(f"{changed} rows changed likelihood regime at the estimate; refitted")
    return False


#: Above this many rows, Newton and the Hessian run on a random subsample of this size
#: (the Hessian is a sum over rows: scaled by n / SUBSAMPLE its relative error is about
#: 1 / sqrt(SUBSAMPLE) times the rows' spread of curvature).
SUBSAMPLE = 10000
#: Newton on the subsample stops at this decrement (nats) when all rows follow: within
#: 0.15 of the subsample's standard errors, which the full-data steps then remove.
SUB_TOL = 1e-2
#: The full-data steps stop at this decrement (nats): within 0.015 standard errors of the
#: optimum. Below it the differences' own noise (~1e-5 nats with 1e5 rows) takes over.
FULL_TOL = 1e-4
#: With pose error (:func:`full_stage`), below this decrement (~0.2 standard errors from
#: the optimum) the steps end: the quasi-Newton step is taken (one value: kept when f is
#: lower there), the Hessian by central differences there, and one Newton step with it,
#: unevaluated, ends them. The steps' gradients before it are forward differences
#: (:func:`search.forward_gradient`, 4 evaluations instead of 8 with 4 parameters); the
#: end's is central, from the Hessian's stencil. On six 1e5-row pose-error campaigns of
#: the bench's kind (seeds 0-5; 3e-3 in place and central gradients before) 40, 59, 50,
#: 68, 50, 41 -> 31, 43, 43, 44, 39, 33 evaluations on all rows, the estimates within
#: 0.0011 standard errors, the standard errors of kappa_eq and r_en within 0.8 % and of
#: attitude_sigma within 7 %. Against a Hessian at the optimum (seeds 0-2) those of
#: attitude_sigma were within 4.9 % (before 2.1 %); finishing farther out (5e-2, 1e-1)
#: moved them by 5-17 %: that curvature changes over a few tenths of its s.e.
FULL_FINISH_TOL = 2e-2
#: Below this decrement (~0.08 standard errors: the finish of the design before) the
#: stencil of the end is taken where the steps stand, not a step further: its forward
#: points are the stencil's (5 evaluations on all rows fewer).
FULL_FINISH_NEAR = 3e-3


def subset(rows: Rows, idx) -> Rows:
    return rows.take(idx, track=False)


#: The mounting scan's grid (rad): pitch and roll from -12 to +12 deg in 3 deg steps.
MOUNT_GRID = np.radians(np.arange(-12.0, 12.5, 3.0))


def mount_scan(rows: Rows, start: Params, free) -> tuple[Params, int]:
    """``start`` with the mounting bias (pitch and roll, those in ``free``) at the best
    point of :data:`MOUNT_GRID`, one angle at a time, twice, at the naive kappa_eq and a
    1 % relative pose error; and the number of evaluations. Why: a bias of a few degrees
    misplaces the field direction of every row, and from 0 the search ran r_en to its
    bound (exact poses, 3 / -2 deg on the study's radial walk) before the bias was found."""
    geo = rows.geo
    probe = replace(start, pose_sigma=0.01) if rows.moments is None else start
    n = 0
    for _round in range(2):
        for name in ("mount_pitch", "mount_roll"):
            if name not in free:
                continue
            k_med = median_kappa(replace(rows, geo=mounted(geo, probe.mount_pitch, probe.mount_roll)), start.r_inner)
            if math.isfinite(k_med):
                probe = replace(probe, kappa_eq=k_med)
            scan = Likelihood(rows)
            best = (math.inf, getattr(probe, name))
            for v in MOUNT_GRID:
                trial = replace(probe, **{name: float(v)})
                scan.choose_regimes(trial)
                f = scan.nll(trial)
                if f < best[0]:
                    best = (f, float(v))
            n += scan.n_evals
            probe = replace(probe, **{name: best[1]})
    return replace(start, mount_pitch=probe.mount_pitch, mount_roll=probe.mount_roll), n


def run_stages(
    rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], start: Params | None,
    full: bool = True, prev: "NewtonResult | None" = None, lead_in: bool = False,
):
    """Pilot + Newton (+ the full-data stage for big tables, :func:`full_stage`, unless
    ``full`` is False: then the result is the subsample's) for the parameters ``free``.
    ``start``: skip the pilot (a previous pass's estimate; ``prev``: that pass's result).
    ``lead_in``: the caller follows a big table's subsample search with :func:`full_stage`
    whatever it finds (the errors-in-variables model's third pass), so that search is only
    a start: its quasi-Newton steps take forward-difference gradients (4 evaluations
    instead of 8 with 4 parameters; on the 1e5-row pose-error bench campaign, seed 0, that
    search took 31 evaluations instead of 48)."""
    n = rows.k.shape[0]
    big = n > SUBSAMPLE and "time_offset" not in free  # the pose track needs every row
    if big:
        rng = np.random.default_rng(np.random.SeedSequence(options.seed, spawn_key=(0x5B,)))
        sub = subset(rows, np.sort(rng.choice(n, SUBSAMPLE, replace=False)))
    else:
        sub = rows
    n_evals = 0
    warm = prev if start is not None else None
    if start is None:  # pilot on (at most) the subsample
        start = base
        if "time_offset" in free and rows.track is not None:
            # A misaligned clock looks like a large pose error (and no noise floor), so
            # find the offset first: a scan over +-3 s at the naive kappa_eq.
            k_med = median_kappa(sub, base.r_inner)
            probe = replace(base, kappa_eq=k_med if math.isfinite(k_med) else base.kappa_eq, pose_sigma=0.01)
            scan = Likelihood(sub)
            best = (math.inf, 0.0)
            for dt in OFFSET_GRID:
                trial = replace(probe, time_offset=float(dt))
                scan.choose_regimes(trial)
                v = scan.nll(trial)
                if v < best[0]:
                    best = (v, float(dt))
            n_evals += scan.n_evals
            start = replace(start, time_offset=best[1])
            sub = replace(sub, geo=sub.track.geometry(best[1]))  # pilots below at that offset
        pil = sub  # the rows of the pilots below (their geometry)
        if "mount_pitch" in free or "mount_roll" in free:
            start, n_scan = mount_scan(sub, start, free)
            n_evals += n_scan
            pil = replace(sub, geo=mounted(sub.geo, start.mount_pitch, start.mount_roll))
        if "kappa_eq" in free:
            k_med = median_kappa(pil, base.r_inner)
            if math.isfinite(k_med):
                start = replace(start, kappa_eq=k_med)
        if "pose_sigma" in free and sub.moments is None:  # else the near scatter is GPS error
            start = replace(start, pose_sigma=pilot_sigma(pil, start.kappa_eq, base.r_inner))
        if "r_en" in free:
            eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
            grid_r = np.geomspace(8.0, 1000.0, 15)

            def at(r_en):  # one likelihood per point: the points run on the stencil threads
                like_r = options.likelihood(sub)
                trial = replace(start, r_en=float(r_en))
                like_r.choose_regimes(trial, **eps_kw)
                return like_r.nll(trial)

            values, n_grid = grid_values(at, grid_r)
            n_evals += n_grid
            i = int(np.argmin(values))
            best_r = float(grid_r[i]) if math.isfinite(values[i]) else start.r_en
            if analytic(sub, start, free, options) and 0 < i < len(values) - 1 and np.all(np.isfinite(values[i - 1 : i + 2])):
                # the vertex of the parabola through the best point and its neighbours (in log
                # r_en): Newton from the grid's ratio of 1.4 took 5-8 steps more
                best_r *= math.exp(vertex_shift(values, i, math.log(grid_r[1] / grid_r[0])))
            start = replace(start, r_en=best_r)
    theta = from_params(start, free)
    if "time_offset" in free and rows.track is not None:
        sub = rows  # the likelihood recomputes the geometry from the track at each offset
    steps = None if prev is None else prev.steps
    use_grad = analytic(sub, start, free, options)
    if use_grad:
        like, res = optimise_grad(sub, base, free, theta, options, notes, SUB_TOL if big else DECREMENT_TOL)
    else:
        tol = DECREMENT_TOL if options.tol is None else options.tol
        like, res = optimise(sub, base, free, theta, options, notes, steps, SUB_TOL if big else tol, warm, lead_in and big)
    n_evals += like.n_evals
    if big and res.ok and full:
        like, res, extra = (full_stage_grad if use_grad else full_stage)(rows, base, free, options, notes, res)
        n_evals += extra
    return like, res, n_evals


def block_rows(rows: Rows) -> int:
    """Rows per block for evaluating all ``rows`` (:data:`likelihood.BLOCK_ROWS`). With pose
    error the near-kink rule's temporaries want cache-sized blocks; with exact poses an
    evaluation is many small numpy calls and two threads gain only on halves (1e5 rows:
    47 -> 33 ms wall with a core free; in blocks of 1e4: nothing)."""
    n = rows.k.shape[0]
    return BLOCK_ROWS if rows.moments is not None else max(BLOCK_ROWS, -(-n // 2))


def full_stage(rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], res: "NewtonResult"):
    """From the subsample's estimate, Newton on all rows: the Hessian by differences on all
    rows there (a subsample's, scaled, is too noisy for the standard errors: a few rows
    near the noise edge carry much of the curvature), then Newton steps with it until the
    decrement is below FULL_TOL. The subsample's estimate is ~sqrt(n / SUBSAMPLE)
    standard errors away, where the Hessian is the optimum's to O(1 / sqrt(n)): one step
    usually lands, and the gradient at the new point confirms it. With pose error the
    steps' gradients are forward differences, and once the decrement is below
    FULL_FINISH_TOL the quasi-Newton step is taken, the Hessian (and the gradient) by
    central differences there and one Newton step with it, not evaluated, ends the stage
    (``finish`` of :func:`search.newton` (BFGS)). The per-row log P of that last
    gradient's points are kept for the sandwich's scores (:func:`row_scores`, taken
    there: :attr:`NewtonResult.evaluated`)."""
    n = rows.k.shape[0]
    scale = n / SUBSAMPLE
    full = options.likelihood(rows)
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    full.choose_regimes(to_params(base, free, res.theta), **eps_kw)
    full.remember = 4 * len(free) + 8
    if options.likelihood is Likelihood:  # (the benchmark's alternatives draw per-row noise)
        full.block, full.threads = block_rows(rows), parallel.STENCIL_THREADS
    # Differences of 0.3 standard errors of all rows, from the scaled subsample Hessian.
    live = np.flatnonzero(~res.active)
    try:
        se_live = np.sqrt(np.maximum(np.diag(np.linalg.inv(res.hess[np.ix_(live, live)] * scale)), 1e-18))
    except np.linalg.LinAlgError:
        se_live = res.steps[live] / 0.3 / math.sqrt(scale)
    steps = res.steps.copy()
    steps[live] = np.clip(0.3 * se_live, 1e-7, 0.05)
    # With two live parameters the Hessian by differences costs two evaluations more than
    # the gradient and saves a step or two; with more, the scaled subsample's is cheaper.
    hess0 = None if live.size <= 2 else res.hess * scale
    # (with exact poses the curvature wavers more over 0.08 s.e.: q's s.e. moved 4.7 % on a
    # 1e5-row campaign, so those fits step on to FULL_TOL as before)
    eiv = rows.moments is not None
    quasi_res = newton(
        Differences(Objective(full, base, free), forward=eiv), res.theta, free, 10, FULL_TOL, h=steps, held=res.active,
        hess0=hess0, finish=FULL_FINISH_TOL if eiv else None, near=FULL_FINISH_NEAR,
    )
    theta, ok_r = quasi_res.theta, quasi_res.ok
    res.theta, res.hess, res.f, res.active, res.evaluated = theta, quasi_res.hess, quasi_res.f, quasi_res.active, quasi_res.evaluated
    res.steps = steps
    res.iterations += quasi_res.iterations
    if not ok_r:
        # Quasi-Newton stalls where the likelihood is not convex (a flat pose-error sigma
        # leaving its floor: BFGS skips the updates); Newton with the Hessian at each step
        # (and its active set) finishes the job, at 21 evaluations a step for 4 parameters.
        again = newton(Differences(Objective(full, base, free)), theta, free, options.max_iter, FULL_TOL, recompute=True, h=steps)
        res.iterations += again.iterations
        if again.ok:
            res.theta, res.hess, res.f, res.steps, res.active = again.theta, again.hess, again.f, again.steps, again.active
            res.evaluated = None
            ok_r = True
    res.full_evals = full.n_evals
    if not ok_r:
        res.ok, res.why = False, "no convergence of the full-data refinement"
    notes.append(f"Newton on a {SUBSAMPLE}-row subsample, then Newton steps and the Hessian on all rows")
    return full, res, full.n_evals


def analytic(rows: Rows, p: Params, free: tuple[str, ...], options: FitOptions) -> bool:
    """Whether the fit of ``free`` takes the analytic-gradient route (:func:`search.newton` with :class:`search.Analytic`):
    exact poses (no errors-in-variables model) and parameters among
    :data:`Likelihood.GRAD_PARAMS`; the others keep central differences. So does a fit of
    r_outer: its likelihood-ratio interval is taken at the first pass's estimate (with
    the initial r_outer), whose optimum is rugged in r_en; the gradient route found a
    lower one on the test campaign, and the interval came out 13 % narrower."""
    return (
        options.likelihood is Likelihood
        and rows.moments is None
        and "r_outer" not in options.free
        and all(n in Likelihood.GRAD_PARAMS for n in free)
        and Likelihood(rows).has_grad(p)
    )


#: :func:`optimise_grad` splits the rows of each evaluation in two halves from this many
#: rows on (a 10,000-row subsample: 9.5 -> ~6 ms wall with a core free).
SPLIT_ROWS = 4000


def optimise_grad(rows: Rows, base: Params, free, theta, options, notes, tol):
    """:func:`optimise` on the analytic-gradient route: a pre-pass to 0.5 nats, then Newton
    to ``tol`` with the S/L split re-chosen until the one at the estimate is the one the
    estimate was found with (a subsample's search: one pass; all rows follow). Its
    evaluations are sequential: from SPLIT_ROWS rows on, each runs its two halves on the
    stencil threads (same values, bit for bit)."""
    like = Likelihood(rows)
    n = rows.k.shape[0]
    if n >= SPLIT_ROWS:
        like.block, like.threads = -(-n // 2), parallel.STENCIL_THREADS
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    obj = GradObjective(like, base, free)
    search = tol > DECREMENT_TOL

    def one_pass(theta, settled, prev):
        # the pre-pass's Hessian, if it differenced one, starts the next pass; a subsample's
        # search needs one only to start all rows from
        hessian = ("some" if search else "final") if settled else "none"
        hess0 = None if prev is None else prev.hess
        res = newton(Analytic(obj), theta, free, options.max_iter, tol if settled else 0.5, hess0=hess0, hessian=hessian)
        return fallback(Analytic(obj), free, res, options, tol if settled else 0.5, hessian=hessian), False

    return like, regime_passes(like, base, free, theta, eps_kw, notes, search, False, one_pass)


#: :func:`full_stage_grad` ends its search on all rows with one Newton step from where the
#: decrement falls below this (~0.045 s.e. from the estimate) with the Hessian by
#: differences taken there, unevaluated: one pass over all rows fewer.
FINISH_TOL = 1e-3


def full_stage_grad(rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], res: "NewtonResult"):
    """:func:`full_stage` on the analytic-gradient route: from the subsample's estimate,
    Newton steps on all rows from the subsample's Hessian scaled by n / SUBSAMPLE (with BFGS
    updates) to FINISH_TOL, then the Hessian by central differences of the gradient there
    and one Newton step with it (not evaluated). The likelihood's curvature in r_en wavers
    by ~15 % over one standard error (rows near the noise edge), so from ~1 s.e. away one
    to three steps are needed, whatever the Hessian: 2-4 + 2p - 1 passes over all rows
    (kappa_eq's column of the Hessian one-sided, :data:`ONE_SIDED`). (The outer product of all rows'
    scores, free with the gradient, is no start: with exact poses the model's 0.01 % pose
    error is wider than the data's, and it has half kappa_eq's curvature.)"""
    full = Likelihood(rows)
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    full.choose_regimes(to_params(base, free, res.theta), **eps_kw)
    full.block, full.threads = block_rows(rows), parallel.STENCIL_THREADS
    hess0 = None if res.hess is None else res.hess * (rows.k.shape[0] / SUBSAMPLE)
    source = Analytic(GradObjective(full, base, free), one_sided=ONE_SIDED)
    again = newton(source, res.theta, free, options.max_iter, FULL_TOL, hess0=hess0, finish=FINISH_TOL)
    again.iterations += res.iterations
    again.full_evals = full.n_evals
    if not again.ok:
        again.why = "no convergence of the full-data refinement"
    notes.append(f"Newton on a {SUBSAMPLE}-row subsample, then Newton steps and the Hessian on all rows")
    return full, again, full.n_evals


def fit_r_outer(like: Likelihood, params: Params, rows: Rows) -> tuple[float, float, float]:
    """r_outer is an end point (the largest d the receiver shows): its likelihood is not
    quadratic, so it gets a bounded 1-D search with the other parameters held, and a
    likelihood-ratio interval (ΔNLL = 1.92) whose width / 3.92 is reported as its s.e.
    Returns (r_outer, se, nll)."""
    from scipy.optimize import brentq, minimize_scalar

    max_d = int(np.max(rows.k))
    lo = (max_d - 0.5) / 100.0 + 1e-7
    hi = max(lo, params.r_outer) + 2.0
    f = lambda r: like.nll(replace(params, r_outer=float(r)))  # noqa: E731
    best = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    r, f0 = float(best.x), float(best.fun)
    g = lambda x: f(x) - f0 - 1.92  # noqa: E731
    left = brentq(g, lo, r, xtol=1e-7) if g(lo) > 0 else lo
    right = brentq(g, r, hi, xtol=1e-7) if g(hi) > 0 else hi
    return r, (right - left) / 3.92, f0


