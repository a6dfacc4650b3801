"""Maximum-likelihood calibration of the receiver model (issue 6).

:func:`fit_table` validates a :class:`Table`, starts from a pilot (median kappa_eq on
near rows, the pose error from their scatter, a grid over r_en), then runs a projected,
damped Newton method on the negative log-likelihood with central-difference derivatives
in the optimiser's scale (log for kappa_eq, lengths and pose_sigma; seconds for
time_offset). With exact poses (no errors-in-variables model) the fit of kappa_eq, r_en
and pose_sigma takes the likelihood's analytic gradient instead (:func:`_newton_grad`:
one pass per point, the Hessian by central differences of the gradient).

Standard errors come from the observed information, the Hessian at the optimum, with
difference steps re-set to 0.3 standard errors so they measure the curvature on the
scale of the uncertainty; the delta method maps them back (se(kappa) = kappa
se(log kappa)). Above ``SUBSAMPLE`` rows the search runs on a random subsample (and the
errors-in-variables passes that only move the linearisation sigmas stay there); all rows
are evaluated once, by quasi-Newton steps from the subsample's Hessian scaled by
n / n_sub and the Hessian by differences at the estimate (:func:`_full_stage`; with pose
error at the last point evaluated, < 0.08 standard errors from it, which one unevaluated
Newton step with that Hessian then closes).
"""

from __future__ import annotations

import atexit
import math
import os
import pickle
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .likelihood import (
    BLOCK_ROWS,
    FREE_PARAMS,
    LINEAR,
    Geometry,
    Likelihood,
    Params,
    Regimes,
    PoseTrack,
    Rows,
    from_params,
    geometry,
    rows_from_table,
    simulate,
    to_params,
)
from .pose_error import MAX_SD, PoseMoments, pose_moments, posterior_attitudes, posterior_positions
from .table import FitInputError, Table, TimeStamps, check_times, gps_scale
from .worker import Worker, WorkerError

MIN_ROWS = 50
#: 90 % of rows within this ratio of distances is "no spread".
MIN_SPREAD = 1.25
#: Optimiser box (natural units); an estimate pinned at an edge has not converged.
BOUNDS = {
    "kappa_eq": (1e-6, 1e6),
    "r_en": (0.5, 1e4),
    "q": (1e-3, 1e3),  # q_y / q_x
    "r_outer": (0.05, 1e4),
    "pose_sigma": (1e-4, 0.5),
    "time_offset": (-30.0, 30.0),
    "height_offset": (-5.0, 5.0),  # m
    # Below 5 mm and 0.05 deg the pose error is lost in the 1 cm rounding: the likelihood
    # is flat there, and Newton crept along it for 60 iterations on exact poses.
    "gps_sigma": (0.005, 30.0),  # m
    "attitude_sigma": (math.radians(0.05), 0.5),  # rad
}
#: Parameters that may sit at their lower bound on exact poses (held there, with a note).
MAY_VANISH = ("pose_sigma", "gps_sigma", "attitude_sigma")
#: pose_sigma under the errors-in-variables model when not given (its lower bound: a
#: larger floor biased r_en by +0.6 % on exact poses in development).
EIV_POSE_SIGMA = 1e-4
#: What ``arva-bench fit`` estimates by default: GPS and attitude error from the data
#: (pose_sigma then stays at its 0.1 % floor, which keeps the ball's edge smooth).
EIV_FREE = ("kappa_eq", "r_en", "gps_sigma", "attitude_sigma")
#: Where the errors-in-variables rule is first evaluated when the sigmas are fitted
#: (horizontal m, attitude rad); floors for the re-evaluation at the estimate.
EIV_START = (0.5, math.radians(1.0))
EIV_FLOOR = (0.01, math.radians(0.1))
#: Fewer bandwidths of data than this under the time-block meat, and the fit says its
#: standard errors run short: the long-run variance is then estimated from a handful of
#: windows (10-minute campaigns, ~6 of them, covered 80-83 % of kappa_eq in
#: docs/accuracy.md (b); 30 minutes, ~11, 88-95 %).
FEW_WINDOWS = 8
#: The time-offset scan (:func:`offset_scan`; a fit of the offset starts from the same
#: grid): offsets tried (s), rows scanned (a seeded subsample: detection, not estimation),
#: and how many nats on them the best offset must gain on 0 before the offset is fitted.
#: The likelihood's gains are inflated by pose errors correlated in time (the sandwich's
#: meat is several times its Hessian), so the threshold comes from emulated campaigns,
#: not a chi-square quantile (docs/calibration.md section 2, "Time offset").
OFFSET_GRID = np.arange(-3.0, 3.0001, 0.25)
OFFSET_ROWS = 2000
OFFSET_GAIN = 40.0
MAX_ITER = 60
#: Stop when the predicted gain to the optimum, g' H^-1 g / 2, is below this (nats):
#: the estimate is then within 0.005 standard errors of the optimum.
DECREMENT_TOL = 1e-5


@dataclass
class FitOptions:
    #: The library default is the relative pose error only; the command line (and
    #: :data:`EIV_FREE`) fits the errors-in-variables sigmas too.
    free: tuple[str, ...] = ("kappa_eq", "r_en", "pose_sigma")
    base: Params = Params()
    eps_split: float | None = None  # None: likelihood.EPS_SPLIT
    max_iter: int = MAX_ITER
    seed: int = 0  # for the simulated outcomes of the Fisher information
    expected_se: bool = False  # also compute the expected (Fisher) information, for comparison
    likelihood: type = Likelihood  # another approximation, for the accuracy/time table
    # "hac": with the errors-in-variables model, the sandwich with a time-block (Newey-West)
    # meat; "model" (and always without it: rows independent given exact poses): inverse Hessian
    covariance: str = "hac"
    eiv_floor: bool = True  # errors-in-variables: pose_sigma at EIV_POSE_SIGMA unless fitted (False: base's)
    # errors-in-variables with time_offset neither fitted nor given (base.time_offset 0):
    # look for a clock offset between the receiver and the pose streams (:func:`offset_scan`)
    # and fit it when the poses fit clearly better at one; False: hold it at 0 unseen
    scan_offset: bool = True


@dataclass
class FitResult:
    source: str
    params: Params
    free: tuple[str, ...]
    estimate: dict[str, float]
    se: dict[str, float]
    cov_theta: NDArray[np.float64]  # covariance in the optimiser's scale
    log_likelihood: float
    n_rows: int
    n_censored: int
    n_used: int
    converged: bool
    message: str
    iterations: int
    n_evals: int
    seconds: float
    naive: dict[str, float]
    exact_fraction: float
    notes: list[str] = field(default_factory=list)
    expected_information: NDArray[np.float64] | None = None  # only with FitOptions.expected_se
    se_model: dict[str, float] = field(default_factory=dict)  # inverse-Hessian s.e. (rows independent)
    hac_lag: float = float("nan")  # the Newey-West bandwidth used (s)
    separable: bool = True  # False: pose error and EMI noise could not be told apart
    n_pose_dropped: int = 0  # rows left out: the pose error hides where they were
    n_evals_all_rows: int = 0  # of n_evals, those on all rows (the rest: a subsample's, or the pilot's)
    stamps: TimeStamps | None = None  # duplicated stamps, repeated slots and gaps in t (counted, kept)

    def to_json(self) -> dict:
        out: dict = {"source": self.source}
        for name in ("kappa_eq", "r_en", "r_outer", "pose_sigma", "time_offset", "gps_sigma", "attitude_sigma", "height_offset"):
            out[name] = getattr(self.params, name)
            if name in self.free:
                out[f"{name}_se"] = self.se.get(name)
        out["gps_sigma_vertical"] = self.params.gps_ratio * self.params.gps_sigma
        out["q"] = list(self.params.q)
        if "q" in self.free:
            out["q_ratio"] = self.estimate["q"]
            out["q_ratio_se"] = self.se.get("q")
        out["r_inner"] = self.params.r_inner
        out["antennas"] = self.params.antennas
        out["moment"] = 1.0
        out.update(
            n_rows=self.n_rows,
            n_censored=self.n_censored,
            n_used=self.n_used,
            log_likelihood=self.log_likelihood,
            converged=self.converged,
            message=self.message,
            iterations=self.iterations,
            likelihood_evaluations=self.n_evals,
            fit_seconds=self.seconds,
            free=list(self.free),
            correlation=_correlation(self.cov_theta, self.free),
            naive=self.naive,
            exact_fraction=self.exact_fraction,
            notes=self.notes,
            se_model=self.se_model,
            covariance_lag_seconds=self.hac_lag,
            separable=self.separable,
            rows_dropped_for_pose_error=self.n_pose_dropped,
            time_stamps=None if self.stamps is None else self.stamps.to_json(),
        )
        return _finite_or_none(out)


def _finite_or_none(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_none(v) for v in obj]
    return obj


def _correlation(cov: NDArray, names: tuple[str, ...]) -> dict[str, float]:
    out = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            den = math.sqrt(cov[i, i] * cov[j, j]) if cov[i, i] > 0 and cov[j, j] > 0 else float("nan")
            out[f"{names[i]}:{names[j]}"] = float(cov[i, j] / den) if den == den and den > 0 else float("nan")
    return out


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


def usable(rows: Rows) -> Rows:
    """Drop rows with the receiver exactly at the transmitter (no direction: no information)."""
    keep = np.isfinite(rows.geo.log_r)
    if keep.all():
        return rows
    return rows.take(keep)


# -- naive estimates ------------------------------------------------------------------


def naive_fit(rows: Rows, r_inner: float = 3.0) -> dict[str, float]:
    """Least squares on the detected mid-zone rows only (what one would do by hand).

    kappa: log-space least squares of d against the noise-free prediction,
    log kappa = mean(3 log(d/100) - 3 log r + log|g_xy|). r_en: least squares of the
    squared residuals against the small-noise variance eps^2/45, eps = 2 r^3/(r_en^3 |g_xy|).
    Both ignore censoring, rounding and the shape of the noise: biased near the range limit.
    """
    k = rows.k
    mid = k >= 100.0 * r_inner + 1
    if mid.sum() < 3:
        return {"kappa_eq": float("nan"), "r_en": float("nan")}
    log_r = rows.geo.log_r[mid]
    gx, gy, _ = rows.geo.g[:, mid]
    log_gxy = np.log(np.hypot(gx, gy))
    y = 3.0 * (np.log(k[mid] / 100.0) - log_r) + log_gxy  # = log kappa + 3 * noise term
    log_kappa = float(np.mean(y))
    res2 = ((y - log_kappa) / 3.0) ** 2
    w = 4.0 * np.exp(6.0 * log_r - 2.0 * log_gxy) / 45.0
    a = float(np.sum(w * res2) / np.sum(w * w))
    r_en = a ** (-1.0 / 6.0) if a > 0 else float("inf")
    return {"kappa_eq": math.exp(log_kappa), "r_en": r_en}


# -- the fit ----------------------------------------------------------------------------


def _box(free) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    lo = np.array([BOUNDS[n][0] if n in LINEAR else math.log(BOUNDS[n][0]) for n in free])
    hi = np.array([BOUNDS[n][1] if n in LINEAR else math.log(BOUNDS[n][1]) for n in free])
    return lo, hi


#: First difference steps, about a third of a typical standard error (log scale).
INITIAL_STEPS = {
    "kappa_eq": 1e-4,
    "r_en": 1e-3,
    "q": 3e-3,
    "r_outer": 1e-4,
    "pose_sigma": 1e-2,
    "time_offset": 0.05,
    "height_offset": 0.01,
    "gps_sigma": 1e-2,
    "attitude_sigma": 1e-2,
}


def _initial_steps(free) -> NDArray[np.float64]:
    return np.array([INITIAL_STEPS[n] for n in free])


def _caps(free) -> NDArray[np.float64]:
    """Largest step per iteration: log pose_sigma may travel far (exact poses)."""
    return np.array([2.0 if n == "time_offset" else 2.5 if n in MAY_VANISH else 0.5 for n in free])


#: Likelihood evaluations at the points of one finite-difference stencil are independent,
#: and numpy releases the GIL inside its array loops: up to this many threads evaluate
#: them at once (each evaluation is unchanged, so the results are too).
STENCIL_THREADS = max(1, min(4, os.cpu_count() or 1))
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


#: Errors-in-variables likelihoods of at least this many rows evaluate a stencil's points
#: shared between a thread here and a worker process (:mod:`.worker`: the same floats;
#: two threads evaluated 10,000-row points only ~1.3x faster than one on two free cores).
#: False: threads only.
STENCIL_WORKER = True
WORKER_ROWS = 5000
_worker: Worker | None = None
_worker_failed = False


def _stencil_pool() -> ThreadPoolExecutor:
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(STENCIL_THREADS, thread_name_prefix="fit-stencil")
    return _pool


def _get_worker() -> Worker | None:
    """The worker process (started on first use), or None where it is not used."""
    global _worker, _worker_failed
    if not STENCIL_WORKER or STENCIL_THREADS == 1:
        return None
    with _pool_lock:
        if _worker_failed:
            return None
        if _worker is None or _worker.owner != os.getpid() or not _worker.alive():
            # (a forked child, e.g. a ProcessPoolExecutor's, must not share its parent's pipes)
            try:
                _worker = Worker()
            except (OSError, ValueError, TypeError):  # no interpreter to start (sys.executable)
                _worker_failed = True
                return None
            atexit.register(_worker.close)
        return _worker


def _drop_worker() -> None:
    """After a failure of the worker: evaluate in this process from now on."""
    global _worker, _worker_failed
    with _pool_lock:
        _worker_failed = True
        if _worker is not None and _worker.owner == os.getpid():
            _worker.proc.kill()
            _worker.proc.wait()
        _worker = None


def worker_cpu() -> float:
    """CPU time (s) the worker process has used so far (0 without one); for benchmarks."""
    w = _worker
    if w is None or w.owner != os.getpid() or not w.alive():
        return 0.0
    try:
        return w.cpu()
    except (OSError, EOFError, WorkerError, pickle.PickleError):
        return 0.0


def _worker_ok(like) -> bool:
    """Whether ``like``'s evaluations may go to the worker: an errors-in-variables
    :class:`Likelihood` (not a subclass) of at least :data:`WORKER_ROWS` rows, with its
    regimes chosen and no pose track (a time-offset fit)."""
    return (
        type(like) is Likelihood and like.rows.moments is not None and like.k.shape[0] >= WORKER_ROWS
        and like.regimes is not None and like.rows.track is None and STENCIL_THREADS > 1
    )  # fmt: skip


def _evaluate(f, points: list) -> list[float]:
    """``[f(x) for x in points]``, on the stencil threads when there are several, or
    (:func:`_worker_ok`) shared with the worker process (:func:`_logps_split`)."""
    if STENCIL_THREADS == 1 or len(points) < 2:
        return [f(x) for x in points]
    like = getattr(f, "like", None)
    if like is not None and _worker_ok(like):
        done = _logps_split(like, [f.params(x) for x in points])
        if done is not None:
            return [-float(np.sum(out)) for out in done]  # like.nll's sum
    return list(_stencil_pool().map(f, points))


def _logps(like: Likelihood, params: list) -> list[NDArray[np.float64]]:
    """``[like.logp(p) for p in params]``, shared with the worker process when
    :func:`_worker_ok` (the same arrays either way)."""
    if len(params) >= 2 and _worker_ok(like):
        done = _logps_split(like, params)
        if done is not None:
            return done
    return [like.logp(p) for p in params]


def _logps_split(like: Likelihood, params: list) -> list[NDArray[np.float64]] | None:
    """``like.logp`` at ``params``, shared out between a stencil thread here (not the
    main thread: an evaluation of all rows stays in one piece) and the worker process, a
    point at a time from the front of one queue (whoever is free takes the next: with
    other jobs on the machine one of the two may be slowed). The worker's per-row log P
    are counted and kept as this process's own (:meth:`Likelihood.record`). Points
    ``like`` kept are not evaluated again. None when the worker is not available."""
    kept = [like.remembered(p) for p in params]  # (taken now: the batch's own results may push them out)
    todo = [i for i, out in enumerate(kept) if out is None]
    w = _get_worker() if len(todo) >= 2 else None
    if w is None or not w.lock.acquire(blocking=False):
        return None
    queue = iter(todo)
    take = threading.Lock()
    theirs: dict[int, NDArray[np.float64]] = {}

    def nxt():
        with take:
            return next(queue, None)

    def local() -> dict[int, NDArray[np.float64]]:
        mine = {}
        while (i := nxt()) is not None:
            mine[i] = like.logp(params[i])
        return mine

    here = _stencil_pool().submit(local)
    failed = False
    sent: list[int] = []
    try:
        # two points in flight, so the worker never waits for the round trip
        while len(sent) < 2 and (i := nxt()) is not None:
            w.start(like, [params[i]])
            sent.append(i)
        while sent:
            theirs[sent.pop(0)] = w.results(1)[0]
            if (i := nxt()) is not None:
                w.start(like, [params[i]])
                sent.append(i)
    except (OSError, EOFError, WorkerError, pickle.PickleError):
        failed = True
    finally:
        w.lock.release()
    mine = here.result()
    if failed:
        _drop_worker()
    for i, out in theirs.items():
        like.record(params[i], out)
        kept[i] = out
    for i, out in mine.items():
        kept[i] = out
    return [like.logp(p) if out is None else out for p, out in zip(params, kept)]  # (left by a failed worker)


def _gradient(f, theta, h, f0=None, hessian=False):
    """Central-difference gradient (and Hessian) of f at theta with steps h.

    Off-diagonal terms use the two diagonal points (+e_i + e_j, -e_i - e_j) with the
    axis points already needed for the gradient (error O(h^2), like the four-point rule,
    for half its evaluations): p^2 + p evaluations in all instead of 2p^2.
    """
    p = theta.shape[0]
    f0 = f(theta) if f0 is None else f0
    eye = np.diag(h)
    points = [theta + eye[i] for i in range(p)] + [theta - eye[i] for i in range(p)]
    pairs = [(i, j) for i in range(p) for j in range(i + 1, p)] if hessian else []
    for i, j in pairs:
        points += [theta + eye[i] + eye[j], theta - eye[i] - eye[j]]
    values = _evaluate(f, points)
    fp, fm = np.array(values[:p]), np.array(values[p : 2 * p])
    g = (fp - fm) / (2 * h)
    hess = np.diag((fp - 2 * f0 + fm) / h**2)
    for n, (i, j) in enumerate(pairs):
        fpp, fmm = values[2 * p + 2 * n : 2 * p + 2 * n + 2]
        v = fpp + fmm - fp[i] - fm[i] - fp[j] - fm[j] + 2 * f0
        hess[i, j] = hess[j, i] = v / (2 * h[i] * h[j])
    return g, hess


def _merge(theta, mask, values):
    out = theta.copy()
    out[mask] = values
    return out


def _active(theta, g, lo, hi):
    """Parameters at a bound whose gradient (of f, to be minimised) points outwards."""
    span = hi - lo
    return ((theta <= lo + 1e-9 * span) & (g > 0)) | ((theta >= hi - 1e-9 * span) & (g < 0))


def _solve(hf, gf):
    """Newton step with the Hessian's eigenvalues replaced by their absolute values
    (floored at 1e-6 of the largest), so a saddle or a concave direction still gives a
    descent step of sensible length. Returns (step, modified?)."""
    w, v = np.linalg.eigh(0.5 * (hf + hf.T))
    if not np.all(np.isfinite(w)):
        return None, True
    top = float(np.max(np.abs(w))) if w.size else 1.0
    mod = np.maximum(np.abs(w), 1e-6 * top if top > 0 else 1e-12)
    return -(v @ ((v.T @ gf) / mod)), bool(np.any(w <= 0))


def _line_search(f, theta, step, f0, lo, hi, cap=None, double=True):
    """Backtracking from the full step; if the full step already decreases f, keep
    doubling it while f keeps decreasing (the likelihood is steeper on the barrier side
    of r_en than a quadratic, so Newton steps from there fall short). The full and the
    first doubled step are evaluated together (two threads), which is what a step that
    lands usually costs; the search itself is unchanged."""
    trial = np.clip(theta + step, lo, hi)
    longer = step * 2.0
    if not double:  # quasi-Newton near the optimum: the full step, else backtracking
        f1 = f(trial)
        if f1 < f0:
            return trial, f1
    elif cap is None or not np.any(np.abs(longer) > cap):
        t2 = np.clip(theta + longer, lo, hi)
        f1, f2 = _evaluate(f, [trial, t2])
    else:
        f1, f2 = f(trial), None
    if double and f1 < f0:
        for doubled in range(1, 5):
            if f2 is None or not f2 < f1:
                break
            step, trial, f1 = longer, t2, f2
            longer = step * 2.0
            if doubled == 4 or (cap is not None and np.any(np.abs(longer) > cap)):
                break
            t2 = np.clip(theta + longer, lo, hi)
            f2 = f(t2)
        return trial, f1
    for _ in range(11):
        step = step * 0.5
        trial = np.clip(theta + step, lo, hi)
        f1 = f(trial)
        if f1 < f0:
            return trial, f1
    return None, f0


@dataclass
class _Newton:
    theta: NDArray[np.float64]
    f: float
    hess: NDArray[np.float64] | None
    active: NDArray[np.bool_]
    steps: NDArray[np.float64]
    iterations: int
    ok: bool
    why: str
    full_evals: int = 0  # evaluations on all rows (the full-data stage)
    #: where the last gradient (and the Hessian) was taken when ``theta`` is a Newton step
    #: from there that was not evaluated (:func:`_full_stage`); else None
    evaluated: NDArray[np.float64] | None = None


def _newton(f, theta, free, max_iter, h=None, tol=DECREMENT_TOL) -> _Newton:
    """Projected damped Newton on f (the negative log-likelihood) in the BOUNDS box.

    Steps of the differences start at 1e-3 and are re-set to 0.3 standard errors from the
    current Hessian; convergence needs a Newton decrement below DECREMENT_TOL with steps
    that no longer change by more than a factor 2. A parameter at a bound whose gradient
    points outwards is held there (active set).
    """
    p = len(free)
    lo, hi = _box(free)
    h = _initial_steps(free) if h is None else h.copy()
    cap = _caps(free)
    probe_lo = np.array([n in MAY_VANISH for n in free])
    probe_hi = np.array([n == "r_en" for n in free])
    theta = np.clip(theta, lo, hi)
    f0 = f(theta)
    none = np.zeros(p, bool)
    if not math.isfinite(f0):
        return _Newton(theta, f0, None, none, h, 0, False, "the likelihood is zero at the starting point")
    held = np.zeros(p, bool)  # at a bound with the gradient pointing out: no Hessian row
    shrinks = 0
    for it in range(1, max_iter + 1):
        g = np.zeros(p)
        hess = np.zeros((p, p))
        if held.any():
            gh, _ = _gradient(_Part(f, lambda th_h: _merge(theta, held, th_h)), theta[held], h[held], f0)
            g[held] = gh
        live = np.flatnonzero(~held)
        gl, hl = _gradient(_Part(f, lambda th_l: _merge(theta, ~held, th_l)), theta[live], h[live], f0, hessian=True)
        g[live] = gl
        hess[np.ix_(live, live)] = hl
        if held.any():
            hess[held, held] = 1.0  # placeholder, never used for a step
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(hess))):
            return _Newton(theta, f0, hess, none, h, it, False, "the likelihood is not finite next to the estimate")
        active = _active(theta, g, lo, hi)
        keep = np.flatnonzero(~active)
        if np.any(active & ~held):
            held = active.copy()
            continue  # recompute without the held rows (cheaper, and exact for the rest)
        held = active.copy()
        hf = hess[np.ix_(keep, keep)]
        stepf, modified = _solve(hf, g[keep])
        if stepf is None:
            return _Newton(theta, f0, hess, active, h, it, False, "the Hessian is not finite")
        decrement = -0.5 * float(g[keep] @ stepf)
        if tol >= 0.5 and decrement < tol:
            # The pre-pass only settles the likelihood regimes: close enough, whatever the
            # curvature at these steps (the next pass looks closer).
            return _Newton(theta, f0, hess, active, h, it, True, "converged")
        if modified and decrement < 0.5 and shrinks < 3:
            # Not convex at this step size. Either a difference straddles a steep side (the
            # noise edge: look again with smaller steps) or a flat, curved direction (a
            # pose-error sigma far from its estimate): try the (modified) step first, and
            # keep it if it clearly lowers f.
            step = np.zeros(p)
            step[keep] = stepf
            step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
            trial = np.clip(theta + step, lo, hi)
            f1 = f(trial)
            if f1 < f0 - 1e-3:
                theta, f0 = trial, f1
                continue
            shrinks += 1
            h = h / 3.0
            continue
        new_h = h.copy()
        if not modified:
            w, v = np.linalg.eigh(0.5 * (hf + hf.T))
            se = np.sqrt(np.maximum((v * v) @ (1.0 / np.maximum(w, 1e-300)), 0.0))
            top = np.where(np.isin(np.array(free)[keep], LINEAR), 0.5, 0.05)
            new_h[keep] = np.clip(0.3 * se, 1e-7, top)
        if not modified and decrement < tol:
            if tol > DECREMENT_TOL or np.all(np.abs(np.log(new_h / h)) < math.log(2.0)):
                return _Newton(theta, f0, hess, active, h, it, True, "converged")
            h = new_h  # once more, with steps on the standard-error scale
            continue
        h = new_h
        step = np.zeros(p)
        step[keep] = stepf
        probed = False
        # A parameter heading for a bound where the likelihood flattens (pose_sigma with
        # exact poses; r_en with no noise in the data) would creep there in capped
        # steps: try the bound itself.
        toward_lo = probe_lo & (step < 0) & (theta > lo)
        toward_hi = probe_hi & (step > 0) & ((np.abs(step) >= cap) | (theta > math.log(300.0))) & (theta < hi)
        for i in np.flatnonzero(toward_lo | toward_hi):
            trial = theta.copy()
            trial[i] = lo[i] if toward_lo[i] else hi[i]
            f1 = f(trial)
            # a sigma that no longer matters (exact poses) leaves f flat to rounding: take the bound
            if f1 < f0 or (toward_lo[i] and f1 < f0 + 1e-6):
                theta, f0, probed = trial, f1, True
        if probed:
            continue
        # A pose-error sigma in a flat direction (exact poses: the likelihood barely moves)
        # gets a huge Newton step; clip it alone rather than shrinking every step with it.
        flat = probe_lo & (np.abs(step) > cap)
        if flat.any() and not flat.all():
            step[flat] = np.sign(step[flat]) * cap[flat]
        step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
        trial, f1 = _line_search(f, theta, step, f0, lo, hi, cap)
        if trial is None:
            # Near a steep side (the noise edge) differences over 0.3 standard errors bias
            # the gradient: retry with a gradient from steps ten times smaller.
            gk, _ = _gradient(_Part(f, lambda th_k: _merge(theta, ~active, th_k)), theta[keep], h[keep] / 10.0, f0)
            stepf, _mod = _solve(hf, gk)
            decrement = -0.5 * float(gk @ stepf)
            step = np.zeros(p)
            step[keep] = stepf
            step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
            trial, f1 = _line_search(f, theta, step, f0, lo, hi, cap) if decrement >= tol else (None, f0)
        if trial is None:
            if not modified and decrement < 1e-3:
                return _Newton(theta, f0, hess, active, h, it, True, "converged")
            if shrinks < 4:  # the differences were too coarse here: look closer
                shrinks += 1
                h = h / 3.0
                continue
            return _Newton(theta, f0, hess, active, h, it, False, "no step decreases the negative log-likelihood")
        theta, f0 = trial, f1
    return _Newton(theta, f0, hess, none, h, max_iter, False, f"no convergence after {max_iter} Newton iterations")


def _newton_fixed(
    f, theta, free, h, held, max_iter=10, tol=DECREMENT_TOL, hess0=None, final_hessian=True, probe=False, finish=None
):
    """Quasi-Newton on ``f`` from a good start: the Hessian by differences (steps ``h``) at
    the start, then steps with it, corrected by BFGS updates from the gradient changes
    (the curvature of a pose-error sigma changes over a few standard errors), until the
    decrement is below ``tol``; then the Hessian by differences at the point
    reached (its axis points are the last gradient's: with a memoising ``f`` only the
    diagonal pairs cost). The ``held`` parameters (at a bound) stay where they are; with
    ``probe``, a pose-error sigma stepping toward its lower bound, where the likelihood
    flattens, is tried at the bound once (as :func:`_newton` does) and held there if f is
    no worse: otherwise it creeps down the valley in ever shorter steps (4 of 50 4-hour
    fits ran out of iterations so).
    ``hess0``: start from this Hessian (all parameters) instead; ``final_hessian`` False:
    return the BFGS one (a search's, whose result is only a start). ``finish`` (with
    ``final_hessian``; above ``tol``): once the decrement is below it, the Hessian by
    differences is taken where the search stands (the final one, taken a step earlier)
    and one Newton step with it ends the search, unevaluated (its f is the quadratic
    model's, f0 - decrement), if that decrement is below ``finish`` too; else the steps go
    on with that Hessian. Saves the last line-search point and gradient.
    Returns (theta, f, Hessian of the live parameters, iterations, converged, held, at):
    ``at`` is where that Hessian and the last gradient were taken when ``theta`` is the
    unevaluated step from there, else None."""
    lo, hi = _box(free)
    cap = _caps(free)
    held = held.copy()
    probe_lo = np.array([probe and n in MAY_VANISH for n in free])
    probed = np.zeros(len(free), bool)
    live = np.flatnonzero(~held)
    point = {"theta": theta}
    sub = _Part(f, lambda th_l: _merge(point["theta"], ~held, th_l))
    f0 = f(theta)
    if hess0 is None:
        g, hl = _gradient(sub, theta[live], h[live], f0, hessian=True)
    else:
        (g, _), hl = _gradient(sub, theta[live], h[live], f0), hess0[np.ix_(live, live)]
    moved, ok, it = hess0 is not None, False, 0
    hq = hl.copy()
    differenced = None if hess0 is not None else theta  # where hl is the Hessian by differences
    for it in range(1, max_iter + 1):
        stepf, _mod = _solve(hq, g)
        if stepf is None:
            break
        decrement = -0.5 * float(g @ stepf)
        if finish is not None and final_hessian and tol <= decrement < finish and differenced is not theta:
            _g, hl = _gradient(sub, theta[live], h[live], f0, hessian=True)  # axis points: the last gradient's
            differenced, hq = theta, hl.copy()
            stepf, modified = _solve(hl, g)
            if stepf is None:
                break
            decrement = -0.5 * float(g @ stepf)
            end = theta.copy()
            end[live] += stepf
            if not modified and decrement < finish and np.all((end >= lo) & (end <= hi)):
                return end, f0 - decrement, hl, it, True, held, theta
        if decrement < tol:
            ok = True
            break
        step = np.zeros(len(free))
        step[live] = stepf
        step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
        took = False
        for i in np.flatnonzero(probe_lo & ~held & ~probed & (step < 0) & (theta > lo)):
            probed[i] = True
            trial = theta.copy()
            trial[i] = lo[i]
            f1 = f(trial)
            if f1 < f0 + 1e-6:
                keep = [k for k, j in enumerate(live) if j != i]
                theta, f0, took = trial, f1, True
                point["theta"] = theta
                held[i] = True
                live = np.flatnonzero(~held)
                hq, hl = hq[np.ix_(keep, keep)], hl[np.ix_(keep, keep)]
        if took:
            moved = True
            g, _ = _gradient(sub, theta[live], h[live], f0)
            continue
        trial, f1 = _line_search(f, theta, step, f0, lo, hi, double=False)
        if trial is None:
            ok = True
            break
        s_l = (trial - theta)[live]
        theta, f0 = trial, f1
        point["theta"] = theta
        g_new, _ = _gradient(sub, theta[live], h[live], f0)
        y = g_new - g
        g, moved = g_new, True
        ys = float(y @ s_l)
        hs = hq @ s_l
        shs = float(s_l @ hs)
        if ys > 1e-12 * max(shs, 1e-300) and shs > 0:
            hq = hq + np.outer(y, y) / ys - np.outer(hs, hs) / shs
    if not final_hessian:
        return theta, f0, hq, it, ok, held, None
    if moved and differenced is not theta:
        _g, hl = _gradient(sub, theta[live], h[live], f0, hessian=True)
    return theta, f0, hl, it, ok, held, None


# -- the likelihood as an objective ----------------------------------------------------------


class _Objective:
    """theta -> negative log-likelihood, for fixed regimes."""

    def __init__(self, like: Likelihood, base: Params, free: tuple[str, ...]) -> None:
        self.like, self.base, self.free = like, base, free

    def params(self, theta) -> Params:
        return to_params(self.base, self.free, theta)

    def __call__(self, theta) -> float:
        return self.like.nll(self.params(theta))


class _Part:
    """``obj`` as a function of some of the coordinates (``full`` completes them to theta);
    with ``like`` and ``params`` as an :class:`_Objective` has, so that :func:`_evaluate`
    can hand its points to the worker process."""

    def __init__(self, obj, full) -> None:
        self.obj, self.full = obj, full
        self.like = obj.like if isinstance(obj, _Objective) else None

    def params(self, x) -> Params:
        return self.obj.params(self.full(x))

    def __call__(self, x) -> float:
        return self.obj(self.full(x))


def _convex(res: "_Newton") -> bool:
    """Whether ``res`` has a Hessian worth starting quasi-Newton steps from (positive
    definite in its live parameters)."""
    if res.hess is None:
        return False
    live = np.flatnonzero(~res.active)
    w = np.linalg.eigvalsh(res.hess[np.ix_(live, live)]) if live.size else np.ones(1)
    return bool(np.all(np.isfinite(w)) and np.all(w > 0))


def _still_held(like: Likelihood, base: Params, free, theta, h, prev: "_Newton") -> bool:
    """Whether every parameter ``prev`` held at a bound still has its gradient pointing
    out there (on ``like``, at ``theta``): quasi-Newton keeps them held, so a flat
    pose-error sigma the first pass pinned to its floor must be free to leave it (Newton
    re-checks the active set at each iteration). Two evaluations per held parameter."""
    held = prev.active
    if not held.any():
        return True
    f = _Objective(like, base, free)
    lo, hi = _box(free)
    g_held, _ = _gradient(_Part(f, lambda th_h: _merge(theta, held, th_h)), theta[held], h[held])
    g = np.zeros(len(free))
    g[held] = g_held
    return bool(np.all(_active(theta, g, lo, hi)[held]))


def _quasi(like: Likelihood, base: Params, free, theta, options, h, tol, prev: "_Newton") -> "_Newton":
    """Quasi-Newton (:func:`_newton_fixed`) on ``like`` from ``prev``'s Hessian and bounds."""
    held = prev.active.copy()
    h = prev.steps if h is None else h
    theta_n, fval, hq, it, ok, held, _at = _newton_fixed(
        _Objective(like, base, free), theta, free, h, held, options.max_iter, tol, prev.hess
    )
    hess = np.zeros((len(free), len(free)))
    live = np.flatnonzero(~held)
    hess[np.ix_(live, live)] = hq
    if held.any():
        hess[held, held] = 1.0  # placeholder, as in _newton
    why = "converged" if ok else "no convergence of the quasi-Newton search"
    return _Newton(theta_n, fval, hess, held, h, it, ok, why)


def _optimise(rows: Rows, base: Params, free, theta, options, notes, h=None, tol=DECREMENT_TOL, warm=None):
    """Newton with the S/L split re-chosen until the one at the estimate is the one the
    estimate was found with (the first pass stops early, at a decrement of 0.5 nats, the
    others at ``tol``; from a ``warm`` start, the previous pass's estimate, the first
    pass goes to ``tol`` too). A subsample's search (``tol`` above DECREMENT_TOL) stops
    after one full pass: all rows follow, with the split chosen at its estimate; it takes
    quasi-Newton steps from the previous pass's Hessian (``warm``: a :class:`_Newton` from
    rows linearised at other sigmas; else the 0.5-nat pass's)."""
    like = options.likelihood(rows)
    if rows.moments is not None:
        # quasi-Newton's final Hessian by differences re-visits the last gradient's axis
        # points (8 of its 20 with 4 parameters): kept, as on all rows (_full_stage)
        like.remember = 4 * len(free) + 8
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    search = tol > DECREMENT_TOL
    if warm is not None and search and _convex(warm):
        like.choose_regimes(to_params(base, free, theta), **eps_kw)
        if _still_held(like, base, free, theta, warm.steps if h is None else h, warm):
            return like, _quasi(like, base, free, theta, options, h, tol, warm)
    iters = 0
    res = None
    for _pass in range(4):
        like.choose_regimes(to_params(base, free, theta), **eps_kw)
        split = like.regimes.exact.copy()
        settled = _pass > 0 or warm is not None
        if settled and search and res is not None and _convex(res) and _still_held(like, base, free, theta, h, res):
            res = _quasi(like, base, free, theta, options, h, tol, res)
            res.iterations += iters
            return like, res
        res = _newton(_Objective(like, base, free), theta, free, options.max_iter, h, tol if settled else 0.5)
        iters += res.iterations
        theta, h = res.theta, res.steps
        if not res.ok or (settled and search):
            break
        if _regimes_settled(like, to_params(base, free, theta), eps_kw, split, settled, notes):
            break
    res.iterations = iters
    return like, res


def _regimes_settled(like: Likelihood, p: Params, eps_kw: dict, split, settled: bool, notes: list[str]) -> bool:
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


# -- Fisher information, for comparison ------------------------------------------------------


def _scores(like: Likelihood, base: Params, free: tuple[str, ...], theta, h, live=None):
    """Per-row central-difference gradients of log P (N, p) (columns ``live`` only)."""
    cols = range(len(free)) if live is None else list(live)
    scores = np.empty((like.k.shape[0], len(cols)))
    points = []
    for j in cols:
        e = np.zeros(len(free))
        e[j] = h[j]
        points += [to_params(base, free, theta + e), to_params(base, free, theta - e)]
    outs = _logps(like, points)
    for c, j in enumerate(cols):
        up, down = outs[2 * c], outs[2 * c + 1]
        scores[:, c] = (up - down) / (2.0 * h[j])
    return scores


def expected_information(like: Likelihood, base: Params, free: tuple[str, ...], theta, seed: int = 0, reps: int = 8):
    """E[sum_i s_i s_i^T] at theta, by simulating every row's outcome from the fitted model
    (:func:`likelihood.simulate`) ``reps`` times. Used by the coverage study in
    docs/calibration.md, not by the fit."""
    params = to_params(base, free, theta)
    geo = like._geo(params)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xF1,)))
    h = np.array([0.01 if n == "time_offset" else 1e-4 for n in free])
    info = np.zeros((len(free), len(free)))
    for _ in range(reps):
        sim = Likelihood(Rows(simulate(geo, params, rng), like.rows.geo, like.rows.track), like.regimes)
        s = _scores(sim, base, free, theta, h)
        info += s.T @ s
    return info / reps


# -- pilot values ------------------------------------------------------------------------------


def _median_kappa(rows: Rows, r_inner: float) -> float:
    """kappa_eq from the median of 3 log(d / dxy0) over mid-zone rows closer than 25 m."""
    k = rows.k
    mid = (k >= 100.0 * r_inner + 1) & (rows.geo.log_r < math.log(25.0))
    if mid.sum() < 3:
        mid = k >= 100.0 * r_inner + 1
    if mid.sum() < 1:
        return float("nan")
    gx, gy, _ = rows.geo.g[:, mid]
    y = 3.0 * (np.log(k[mid] / 100.0) - rows.geo.log_r[mid]) + np.log(np.hypot(gx, gy))
    return math.exp(float(np.median(y)))


def pilot_sigma(rows: Rows, kappa: float, r_inner: float) -> float:
    """The spread of log d on rows closer than 12 m (EMI negligible) beyond what the 1 cm
    rounding explains, from the median absolute deviation."""
    k = rows.k
    log_r = rows.geo.log_r
    gx, gy, gz = rows.geo.g
    near = (k > 0) & (log_r < math.log(12.0))
    if near.sum() < 10:
        return 1e-3
    mid = k > 100 * r_inner
    with np.errstate(divide="ignore"):
        gn = np.where(mid, np.hypot(gx, gy), np.sqrt(gx * gx + gy * gy + gz * gz))
        pred = log_r + (math.log(kappa) - np.log(gn)) / 3.0
    res = (np.log(np.maximum(k, 1) / 100.0) - pred)[near]
    res = res[np.isfinite(res)]
    if res.size < 10:
        return 1e-3
    mad = 1.4826 * float(np.median(np.abs(res - np.median(res))))
    rounding = float(np.median(1.0 / k[near])) / math.sqrt(12.0)
    return float(np.clip(math.sqrt(max(mad * mad - rounding * rounding, 0.0)), BOUNDS["pose_sigma"][0], 0.2))


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
#: With pose error (:func:`_full_stage`), below this decrement (~0.08 standard errors from
#: the optimum) the Hessian by differences is taken where the steps stand and one Newton
#: step with it, unevaluated, ends them: a line-search point and a gradient fewer (9 of
#: ~40 evaluations on all rows, 4 parameters).
FULL_FINISH_TOL = 3e-3


def _subset(rows: Rows, idx) -> Rows:
    return rows.take(idx, track=False)


# -- the fit ------------------------------------------------------------------------------------


def _core(
    rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], start: Params | None,
    full: bool = True, prev: "_Newton | None" = None,
):
    """Pilot + Newton (+ the full-data stage for big tables, :func:`_full_stage`, unless
    ``full`` is False: then the result is the subsample's) for the parameters ``free``.
    ``start``: skip the pilot (a previous pass's estimate; ``prev``: that pass's result)."""
    n = rows.k.shape[0]
    big = n > SUBSAMPLE and "time_offset" not in free  # the pose track needs every row
    if big:
        rng = np.random.default_rng(np.random.SeedSequence(options.seed, spawn_key=(0x5B,)))
        sub = _subset(rows, np.sort(rng.choice(n, SUBSAMPLE, replace=False)))
    else:
        sub = rows
    n_evals = 0
    warm = prev if start is not None else None
    if start is None:  # pilot on (at most) the subsample
        start = base
        if "time_offset" in free and rows.track is not None:
            # A misaligned clock looks like a large pose error (and no noise floor), so
            # find the offset first: a scan over +-3 s at the naive kappa_eq.
            k_med = _median_kappa(sub, base.r_inner)
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
        if "kappa_eq" in free:
            k_med = _median_kappa(sub, base.r_inner)
            if math.isfinite(k_med):
                start = replace(start, kappa_eq=k_med)
        if "pose_sigma" in free and sub.moments is None:  # else the near scatter is GPS error
            start = replace(start, pose_sigma=pilot_sigma(sub, start.kappa_eq, base.r_inner))
        if "r_en" in free:
            eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
            grid_r = np.geomspace(8.0, 1000.0, 15)

            def at(r_en):  # one likelihood per point: the points run on the stencil threads
                like_r = options.likelihood(sub)
                trial = replace(start, r_en=float(r_en))
                like_r.choose_regimes(trial, **eps_kw)
                return like_r.nll(trial)

            values, n_grid = _grid_values(at, grid_r)
            n_evals += n_grid
            i = int(np.argmin(values))
            best_r = float(grid_r[i]) if math.isfinite(values[i]) else start.r_en
            if _analytic(sub, start, free, options) and 0 < i < len(values) - 1 and np.all(np.isfinite(values[i - 1 : i + 2])):
                # the vertex of the parabola through the best point and its neighbours (in log
                # r_en): Newton from the grid's ratio of 1.4 took 5-8 steps more
                best_r *= math.exp(_vertex_shift(values, i, math.log(grid_r[1] / grid_r[0])))
            start = replace(start, r_en=best_r)
    theta = from_params(start, free)
    if "time_offset" in free and rows.track is not None:
        sub = rows  # the likelihood recomputes the geometry from the track at each offset
    steps = None if prev is None else prev.steps
    analytic = _analytic(sub, start, free, options)
    if analytic:
        like, res = _optimise_grad(sub, base, free, theta, options, notes, SUB_TOL if big else DECREMENT_TOL)
    else:
        like, res = _optimise(sub, base, free, theta, options, notes, steps, SUB_TOL if big else DECREMENT_TOL, warm)
    n_evals += like.n_evals
    if big and res.ok and full:
        like, res, extra = (_full_stage_grad if analytic else _full_stage)(rows, base, free, options, notes, res)
        n_evals += extra
    return like, res, n_evals


def _vertex_shift(values, i: int, step: float) -> float:
    """From grid point ``i`` (0 < i < len - 1) to the vertex of the parabola through it and
    its neighbours, for a grid of spacing ``step``: at most one step either way, and 0
    where the three values do not curve upwards."""
    vm, v0, vp = values[i - 1 : i + 2]
    curv = vp - 2.0 * v0 + vm
    if curv > 0:
        return float(np.clip(-0.5 * step * (vp - vm) / curv, -step, step))
    return 0.0


def _grid_values(f, grid) -> tuple[NDArray[np.float64], int]:
    """f on the ``grid`` where the pilot needs it (NaN counts as +inf), and how many
    points that took: every other point, then the two neighbours of the best of those;
    +inf at the points not evaluated. Where f is unimodal on the grid (the likelihood in
    r_en is) its best point and that point's neighbours are among them: the same pilot
    as from every point, with 10 evaluations of 15."""
    values = np.full(len(grid), np.inf)
    coarse = list(range(0, len(grid), 2))
    values[coarse] = _evaluate(f, [grid[i] for i in coarse])
    values = np.where(np.isnan(values), np.inf, values)
    best = coarse[int(np.argmin(values[coarse]))]
    fine = [i for i in (best - 1, best + 1) if 0 <= i < len(grid)]
    values[fine] = _evaluate(f, [grid[i] for i in fine])
    return np.where(np.isnan(values), np.inf, values), len(coarse) + len(fine)


def block_rows(rows: Rows) -> int:
    """Rows per block for evaluating all ``rows`` (:data:`likelihood.BLOCK_ROWS`). With pose
    error the near-kink rule's temporaries want cache-sized blocks; with exact poses an
    evaluation is many small numpy calls and two threads gain only on halves (1e5 rows:
    47 -> 33 ms wall with a core free; in blocks of 1e4: nothing)."""
    n = rows.k.shape[0]
    return BLOCK_ROWS if rows.moments is not None else max(BLOCK_ROWS, -(-n // 2))


def _full_stage(rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], res: "_Newton"):
    """From the subsample's estimate, Newton on all rows: the Hessian by differences on all
    rows there (a subsample's, scaled, is too noisy for the standard errors: a few rows
    near the noise edge carry much of the curvature), then Newton steps with it until the
    decrement is below FULL_TOL. The subsample's estimate is ~sqrt(n / SUBSAMPLE)
    standard errors away, where the Hessian is the optimum's to O(1 / sqrt(n)): one step
    usually lands, and the gradient at the new point confirms it. With pose error, once
    the decrement is below FULL_FINISH_TOL the Hessian by differences is taken there and
    one Newton step with it, not evaluated, ends the stage (``finish`` of
    :func:`_newton_fixed`). The per-row log P of that last gradient's points are kept for
    the sandwich's scores (:func:`_scores`, taken there: :attr:`_Newton.evaluated`)."""
    n = rows.k.shape[0]
    scale = n / SUBSAMPLE
    full = options.likelihood(rows)
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    full.choose_regimes(to_params(base, free, res.theta), **eps_kw)
    full.remember = 4 * len(free) + 8
    if options.likelihood is Likelihood:  # (the benchmark's alternatives draw per-row noise)
        full.block, full.threads = block_rows(rows), STENCIL_THREADS
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
    theta, fval, h_live, it, ok_r, held, at = _newton_fixed(
        _Objective(full, base, free), res.theta, free, steps, res.active, tol=FULL_TOL, hess0=hess0, probe=True,
        finish=FULL_FINISH_TOL if rows.moments is not None else None,
    )
    live = np.flatnonzero(~held)
    hess = np.zeros_like(res.hess)
    hess[np.ix_(live, live)] = h_live
    if held.any():
        hess[held, held] = 1.0  # placeholder, as in _newton
    res.theta, res.hess, res.f, res.steps, res.active, res.evaluated = theta, hess, fval, steps, held, at
    res.iterations += it
    if not ok_r:
        # Quasi-Newton stalls where the likelihood is not convex (a flat pose-error sigma
        # leaving its floor: BFGS skips the updates); Newton with the Hessian at each step
        # (and its active set) finishes the job, at 21 evaluations a step for 4 parameters.
        again = _newton(_Objective(full, base, free), theta, free, options.max_iter, steps, FULL_TOL)
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


# -- analytic gradients (exact poses) ------------------------------------------------------------


class _GradObjective(_Objective):
    """:class:`_Objective` that also gives the gradient and the per-row scores (N, p) of
    log P from one pass (:meth:`Likelihood.logp_grad`)."""

    def __init__(self, like: Likelihood, base: Params, free: tuple[str, ...]) -> None:
        super().__init__(like, base, free)
        self.cols = [Likelihood.GRAD_PARAMS.index(n) for n in free]

    def value_grad(self, theta):
        logp, d = self.like.logp_grad(to_params(self.base, self.free, theta))
        scores = d[self.cols].T
        return -float(np.sum(logp)), -scores.sum(axis=0), scores


def _analytic(rows: Rows, p: Params, free: tuple[str, ...], options: FitOptions) -> bool:
    """Whether the fit of ``free`` takes the analytic-gradient route (:func:`_newton_grad`):
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


#: Parameters whose column of the all-rows Hessian :func:`_hessian_fd` takes by a forward
#: difference (one pass instead of two): with 3e4-1e5 rows kappa_eq's curvature is smooth
#: (its entry moves by < 1e-5 between steps of 0.1 and 1 s.e.; s.e. unchanged to 1e-4),
#: unlike r_en's. Not below SUBSAMPLE rows: on 1200 rows it moved kappa_eq's s.e. by 2.3 %.
ONE_SIDED = ("kappa_eq",)


def _hessian_fd(obj: _GradObjective, theta, g0, live, h, lo, hi, one_sided=()):
    """Hessian of the ``live`` parameters by differences of the analytic gradient (steps
    ``h``, shortened to stay in the box); the points run on the stencil threads. Central
    differences, as the differences of f they replace: the curvature averaged over +-h.
    The likelihood's curvature in r_en wavers by ~1 % over a tenth of a standard error
    (rows crossing the noise edge), and a one-sided difference followed it (1.7 % on the
    1e5-row campaign of tests/perf/bench_fit_read.py). The columns of ``one_sided``
    parameters are forward differences from ``g0``, the gradient at ``theta``, and their
    off-diagonal entries come from the central columns."""
    hs = np.minimum(h[live], np.maximum(np.minimum(hi[live] - theta[live], theta[live] - lo[live]), 1e-9))
    one = np.array([obj.free[j] in one_sided for j in live], dtype=bool)
    points = []
    for c, j in enumerate(live):
        for sgn in (1.0,) if one[c] else (1.0, -1.0):
            th = theta.copy()
            th[j] += sgn * hs[c]
            points.append(th)
    grads = iter(_evaluate(lambda th: obj.value_grad(th)[1], points))
    cols = []
    for c in range(len(live)):
        up = next(grads)[live]
        cols.append((up - g0[live]) / hs[c] if one[c] else (up - next(grads)[live]) / (2.0 * hs[c]))
    hl = np.stack(cols, axis=1)
    out = 0.5 * (hl + hl.T)
    for a in np.flatnonzero(one):  # the central columns' entries are the better ones
        for b in np.flatnonzero(~one):
            out[a, b] = out[b, a] = hl[a, b]
    return out


def _se_steps(hl, free, live, fallback):
    """Difference steps of 0.3 standard errors from a live-parameter Hessian."""
    steps = fallback.copy()
    try:
        se = np.sqrt(np.maximum(np.diag(np.linalg.inv(hl)), 1e-18))
    except np.linalg.LinAlgError:
        return steps
    top = np.where(np.isin(np.array(free)[live], LINEAR), 0.5, 0.05)
    steps[live] = np.clip(0.3 * se, 1e-7, top)
    return np.where(np.isfinite(steps), steps, fallback)


#: :func:`_newton_grad` leaves the outer product for the Hessian by differences after
#: BHHH_STEPS steps (or two in a row that do not halve the decrement).
BHHH_STEPS = 4


def _newton_grad(
    obj: _GradObjective, theta, free, max_iter, tol, hess0=None, hessian="final", one_sided=(), finish=None
) -> _Newton:
    """Projected Newton on f with the analytic gradient of each point (one pass each).

    Curvature: the outer product of the per-row scores at each point (BHHH; positive
    definite, and the Hessian's expectation at the optimum of a well-specified model) or
    ``hess0`` (a previous Hessian: the scaled one of a subsample), corrected by BFGS
    updates from the gradient changes of each step. The outer product alone can stall (a
    misspecified model, e.g. the wrong r_outer; or exact poses, whose 0.01 % model pose
    error is wider than the data's: it has half kappa_eq's curvature there), and BFGS can
    go astray on a likelihood that is not smooth at the scale of a standard error (1200
    rows: 60 ever shorter steps): after BHHH_STEPS steps with the outer product, or two
    steps in a row that did not halve the decrement, the Hessian by central differences
    of the gradient (:func:`_hessian_fd`, 2p passes) is taken there. Convergence: a
    decrement g' H^-1 g / 2 below ``tol``; then with ``hessian`` "final" the Hessian by
    differences at the estimate (the likelihood's curvature wavers
    by ~1 % over 0.02 standard errors, rows near the noise edge: taken elsewhere it would
    not be the estimate's); "some": a Hessian by differences taken somewhere on the way
    (BFGS-updated; a subsample's, to start all rows from); "none" (a pre-pass): whatever
    curvature was used. Bounds as in :func:`_newton`: a parameter at a bound with its
    gradient pointing out is held, and pose_sigma (r_en) stepping toward a bound where f
    flattens is tried at the bound. ``one_sided``: see :func:`_hessian_fd`. ``finish`` (with
    "final"; a decrement above ``tol``): below it, the Hessian by differences is taken
    where the search stands and one Newton step with it ends the search, unevaluated (its
    f is the quadratic model's: f0 - decrement); if that decrement is still above
    ``finish`` the search goes on as usual."""
    p = len(free)
    lo, hi = _box(free)
    cap = _caps(free)
    h = _initial_steps(free)
    probe_lo = np.array([n in MAY_VANISH for n in free])
    probe_hi = np.array([n == "r_en" for n in free])
    theta = np.clip(theta, lo, hi)
    f0, g, scores = obj.value_grad(theta)
    none = np.zeros(p, bool)
    if not math.isfinite(f0):
        return _Newton(theta, f0, None, none, h, 0, False, "the likelihood is zero at the starting point")
    hq = np.eye(p) if hess0 is None else hess0.copy()
    bhhh = hess0 is None  # the outer product at each point, until a Hessian is differenced
    n_steps, last_dec = 0, math.inf  # steps since the curvature was last renewed
    exact_at = None  # (theta, live parameters) where hq was differenced
    differenced = hess0 is not None and hessian != "final"

    def difference(theta, keep, hk):
        nonlocal h, bhhh, exact_at, differenced, n_steps, last_dec
        h = _se_steps(hk, free, keep, h)
        n_steps, last_dec = 0, math.inf
        hq[np.ix_(keep, keep)] = _hessian_fd(obj, theta, g, keep, h, lo, hi, one_sided)
        bhhh, differenced, exact_at = False, True, (theta.copy(), keep)
        return hq[np.ix_(keep, keep)]

    it = 0
    for it in range(1, max_iter + 1):
        if not (math.isfinite(f0) and np.all(np.isfinite(g))):
            return _Newton(theta, f0, hq, none, h, it, False, "the likelihood is not finite next to the estimate")
        active = _active(theta, g, lo, hi)
        keep = np.flatnonzero(~active)
        if keep.size == 0:
            return _Newton(theta, f0, np.eye(p), active, h, it, True, "converged")
        if bhhh:
            hq[np.ix_(keep, keep)] = scores[:, keep].T @ scores[:, keep]
        hk = hq[np.ix_(keep, keep)]
        stepf, _mod = _solve(hk, g[keep])
        if stepf is None:
            return _Newton(theta, f0, hq, active, h, it, False, "the Hessian is not finite")
        decrement = -0.5 * float(g[keep] @ stepf)
        slow = n_steps >= 2 and decrement > 0.5 * last_dec
        stalled = decrement >= tol and ((bhhh and n_steps >= BHHH_STEPS) or slow)
        here = exact_at is not None and np.array_equal(exact_at[0], theta) and np.array_equal(exact_at[1], keep)
        want = (hessian == "final" and not here) or (hessian == "some" and not differenced)
        finishing = finish is not None and hessian == "final" and decrement < finish and not here
        if stalled or (decrement < tol and want) or finishing:
            hk = difference(theta, keep, hk)
            stepf, _mod = _solve(hk, g[keep])
            if stepf is None:
                return _Newton(theta, f0, hq, active, h, it, False, "the Hessian is not finite")
            decrement = -0.5 * float(g[keep] @ stepf)
            if finishing and decrement < finish:
                end = theta.copy()
                end[keep] += stepf
                if np.all((end >= lo) & (end <= hi)):
                    return _Newton(end, f0 - decrement, hq, active, h, it, True, "converged")
        n_steps += 1
        last_dec = decrement
        if decrement < tol:
            return _Newton(theta, f0, hq if differenced else None, active, h, it, True, "converged")
        step = np.zeros(p)
        step[keep] = stepf
        # A parameter heading for a bound where the likelihood flattens (pose_sigma with
        # exact poses; r_en with no noise in the data): try the bound itself.
        toward_lo = probe_lo & (step < 0) & (theta > lo)
        toward_hi = probe_hi & (step > 0) & ((np.abs(step) >= cap) | (theta > math.log(300.0))) & (theta < hi)
        probed = False
        for i in np.flatnonzero(toward_lo | toward_hi):
            trial = theta.copy()
            trial[i] = lo[i] if toward_lo[i] else hi[i]
            r = obj.value_grad(trial)
            if r[0] < f0 or (toward_lo[i] and r[0] < f0 + 1e-6):
                theta, (f0, g, scores), probed = trial, r, True
        if probed:
            n_steps, last_dec = 0, math.inf
            continue
        flat = probe_lo & (np.abs(step) > cap)
        if flat.any() and not flat.all():
            step[flat] = np.sign(step[flat]) * cap[flat]
        step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
        accepted = None
        for _half in range(12):
            trial = np.clip(theta + step, lo, hi)
            r = obj.value_grad(trial)
            if r[0] < f0:
                accepted = (trial, r)
                break
            step = step * 0.5
        if accepted is None:
            if exact_at is not None and decrement < 1e-3:
                return _Newton(theta, f0, hq, active, h, it, True, "converged")
            return _Newton(theta, f0, hq, active, h, it, False, "no step decreases the negative log-likelihood")
        trial, (f1, g1, s1) = accepted
        d0, d1 = float(g @ (trial - theta)), float(g1 @ (trial - theta))
        if d0 < 0 < d1 and d1 > -0.5 * d0:
            # far past the minimum along the step (the curvature underestimated, as the outer
            # product does on the steep side of r_en): the secant of the slope there
            alt = np.clip(theta + (trial - theta) * (d0 / (d0 - d1)), lo, hi)
            r = obj.value_grad(alt)
            if r[0] < f1:
                trial, (f1, g1, s1) = alt, r
        s_l, y = (trial - theta)[keep], (g1 - g)[keep]  # BFGS on the live block
        ys, hs_ = float(y @ s_l), hk @ s_l
        shs = float(s_l @ hs_)
        if not bhhh and ys > 1e-12 * max(shs, 1e-300) and shs > 0:
            hq[np.ix_(keep, keep)] = hk + np.outer(y, y) / ys - np.outer(hs_, hs_) / shs
        theta, f0, g, scores = trial, f1, g1, s1
    return _Newton(theta, f0, hq, none, h, max_iter, False, f"no convergence after {max_iter} Newton iterations")


#: :func:`_optimise_grad` splits the rows of each evaluation in two halves from this many
#: rows on (a 10,000-row subsample: 9.5 -> ~6 ms wall with a core free).
SPLIT_ROWS = 4000


def _optimise_grad(rows: Rows, base: Params, free, theta, options, notes, tol):
    """:func:`_optimise` on the analytic-gradient route: a pre-pass to 0.5 nats, then Newton
    to ``tol`` with the S/L split re-chosen until the one at the estimate is the one the
    estimate was found with (a subsample's search: one pass; all rows follow). Its
    evaluations are sequential: from SPLIT_ROWS rows on, each runs its two halves on the
    stencil threads (same values, bit for bit)."""
    like = Likelihood(rows)
    n = rows.k.shape[0]
    if n >= SPLIT_ROWS:
        like.block, like.threads = -(-n // 2), STENCIL_THREADS
    eps_kw = {} if options.eps_split is None else {"eps_split": options.eps_split}
    obj = _GradObjective(like, base, free)
    search = tol > DECREMENT_TOL
    iters = 0
    res = None
    hess0 = None
    for _pass in range(4):
        like.choose_regimes(to_params(base, free, theta), **eps_kw)
        split = like.regimes.exact.copy()
        settled = _pass > 0
        # the pre-pass's Hessian, if it differenced one, starts the next pass; a subsample's
        # search needs one only to start all rows from
        hessian = ("some" if search else "final") if settled else "none"
        res = _newton_grad(obj, theta, free, options.max_iter, tol if settled else 0.5, hess0, hessian)
        hess0 = res.hess
        iters += res.iterations
        theta = res.theta
        if not res.ok or (settled and search):
            break
        if _regimes_settled(like, to_params(base, free, theta), eps_kw, split, settled, notes):
            break
    res.iterations = iters
    return like, res


#: :func:`_full_stage_grad` ends its search on all rows with one Newton step from where the
#: decrement falls below this (~0.045 s.e. from the estimate) with the Hessian by
#: differences taken there, unevaluated: one pass over all rows fewer.
FINISH_TOL = 1e-3


def _full_stage_grad(rows: Rows, base: Params, free: tuple[str, ...], options: FitOptions, notes: list[str], res: "_Newton"):
    """:func:`_full_stage` on the analytic-gradient route: from the subsample's estimate,
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
    full.block, full.threads = block_rows(rows), STENCIL_THREADS
    hess0 = None if res.hess is None else res.hess * (rows.k.shape[0] / SUBSAMPLE)
    again = _newton_grad(
        _GradObjective(full, base, free), res.theta, free, options.max_iter, FULL_TOL, hess0, one_sided=ONE_SIDED, finish=FINISH_TOL
    )
    again.iterations += res.iterations
    again.full_evals = full.n_evals
    if not again.ok:
        again.why = "no convergence of the full-data refinement"
    notes.append(f"Newton on a {SUBSAMPLE}-row subsample, then Newton steps and the Hessian on all rows")
    return full, again, full.n_evals


def _fit_r_outer(like: Likelihood, params: Params, rows: Rows) -> tuple[float, float, float]:
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


#: Pose-error sigmas that may be held at their estimate when the Hessian by differences
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


def _sigma0(p: Params, free) -> tuple[float, float, float]:
    """Where to evaluate the errors-in-variables rule: at the current sigmas, floored."""
    h = max(p.gps_sigma, EIV_FLOOR[0])
    return (h, p.gps_ratio * h, max(p.attitude_sigma, EIV_FLOOR[1]))


def eiv_rows(
    rows: Rows, table: Table, sigma0, idx=None, attitude: float | None = None, track: bool = False
) -> tuple[Rows, int]:
    """The rows of ``table`` (``rows``: all of them) for the errors-in-variables model at
    sigmas ``sigma0``: geometry at the expected true receiver poses, the pose-error
    moments, and only rows not at the transmitter whose pose-error spread of log d is
    within pose_error.MAX_SD. Returns (rows, number left out for their pose error).
    ``idx``: only these rows (sorted indices; the positions and the time-offset track
    still come from all of them). ``attitude``: the attitude error the tilts are shrunk
    by (default sigma0's, which is floored for the rule; 0 keeps the logged attitudes).
    The time-offset track is built when ``rows`` has one or ``track`` asks for it."""
    post = posterior_positions(table.rx_pos, table.tx_pos, sigma0[0], sigma0[1])
    quat = posterior_attitudes(table.rx_quat, sigma0[2] if attitude is None else attitude)
    # the geometry at the expected true poses, and so is the time-offset track's (with
    # the logged ones there, any offset but 0 took the shrinkage away: a step in the
    # likelihood at 0 that moved kappa_eq by 1.8 s.e. with the sigmas estimated, 3.4 with
    # them given, when the offset was freed on a 60-minute campaign without one)
    if track or rows.track is not None:
        rows.track = PoseTrack(table, post.pos, quat)
    pos, rx_q, tx_p, tx_q = post.pos, quat, table.tx_pos, table.tx_quat
    if idx is not None:
        rows = rows.take(idx)
        pos, rx_q, tx_p, tx_q = pos[idx], rx_q[idx], tx_p[idx], tx_q[idx]
    rows.geo = geometry(pos, rx_q, tx_p, tx_q)
    rule0 = (sigma0[0], max(sigma0[1] * post.v_factor, 1e-6), sigma0[2])
    rows.moments = mom = _pose_moments(pos, rx_q, tx_p, tx_q, rule0)
    # the likelihood scales the vertical group by gps_ratio * gps_sigma: fold the factor in
    for arr in (mom.m_xy, mom.v_xy, mom.m_3, mom.v_3):
        arr[1] *= post.v_factor**2
    s = np.asarray(sigma0)
    mom = rows.moments
    if rows.gps_scale is None:
        _m, vxy, _m3, v3 = mom.spread(s)
    else:
        w = np.stack([(s[0] * rows.gps_scale) ** 2, (s[1] * rows.gps_scale) ** 2, np.full(rows.k.shape, s[2] ** 2)])
        vxy, v3 = np.einsum("gn,gn->n", w, mom.v_xy), np.einsum("gn,gn->n", w, mom.v_3)
    finite = np.isfinite(rows.geo.log_r)
    keep = finite & (np.maximum(vxy, v3) <= MAX_SD * MAX_SD)
    return rows.take(keep), int(np.sum(finite & ~keep))


#: Above this many rows :func:`_pose_moments` splits the table in two halves.
MOMENT_ROWS = 20_000


def _pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0) -> PoseMoments:
    """:func:`pose_moments` of the two halves of the rows on the stencil threads: it is
    computed row by row, so the halves are the whole's values bit for bit (checked on the
    1e5-row bench campaign; ~0.15 s per call on one thread, three calls per fit). Should
    a half raise (a bad quaternion), the whole is computed again, which raises as before."""
    n = len(rx_pos)
    if STENCIL_THREADS == 1 or n < MOMENT_ROWS:
        return pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0)
    cols = [np.asarray(a) for a in (rx_pos, rx_quat, tx_pos, tx_quat)]
    halves = (slice(0, n // 2), slice(n // 2, n))
    try:
        parts = list(_stencil_pool().map(lambda sl: pose_moments(*(c[sl] for c in cols), sigma0), halves))
    except Exception:  # noqa: BLE001 - the whole table's call below raises it (or not) as before
        return pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0)
    a, b = parts
    return PoseMoments(
        *(np.concatenate([x, y], axis=1) for x, y in ((a.m_xy, b.m_xy), (a.v_xy, b.v_xy), (a.m_3, b.m_3), (a.v_3, b.v_3))),
        a.sigma0, np.concatenate([a.dz_xy, b.dz_xy]), np.concatenate([a.dz_3, b.dz_3]),
    )  # fmt: skip


def model_rows(table: Table, params: Params) -> Rows:
    """The rows and per-row model the fit used for ``params`` (for the report)."""
    rows = rows_from_table(table)
    if params.gps_sigma > 0 or params.attitude_sigma > 0:
        rows.gps_scale = gps_scale(table)
        return eiv_rows(rows, table, _sigma0(params, ()), attitude=params.attitude_sigma)[0]
    return usable(rows)


@dataclass
class OffsetScan:
    """The time-offset scan at a fit's estimate: the best offset on :data:`OFFSET_GRID`
    (s; refined by the parabola through its neighbours) and what it gains on 0 (nats, on
    the rows scanned)."""

    offset: float
    gain: float
    rows: int  # rows scanned (a seeded subsample of at most OFFSET_ROWS)


def offset_scan(table: Table, params: Params, options: FitOptions) -> OffsetScan | None:
    """The negative log-likelihood of ``params`` with the poses taken at t + dt, for dt on
    :data:`OFFSET_GRID`, on (at most) OFFSET_ROWS of the errors-in-variables rows, the
    other parameters held. None when the table has fewer than 4 distinct times (no track)."""
    if np.unique(table.t).shape[0] < 4:
        return None
    rows = rows_from_table(table)  # (eiv_rows builds the track, from the positions it uses)
    rows.gps_scale = gps_scale(table)
    n = rows.k.shape[0]
    idx = None
    if n > OFFSET_ROWS:
        rng = np.random.default_rng(np.random.SeedSequence(options.seed, spawn_key=(0x0F5,)))
        idx = np.sort(rng.choice(n, OFFSET_ROWS, replace=False))
    rows, _dropped = eiv_rows(rows, table, _sigma0(params, ()), idx, attitude=params.attitude_sigma, track=True)

    def at(dt):  # one likelihood per offset (its own regimes): the points run on the stencil threads
        like = options.likelihood(rows)
        trial = replace(params, time_offset=float(dt))
        like.choose_regimes(trial)
        return like.nll(trial)

    values = np.array(_evaluate(at, list(OFFSET_GRID)))
    i = int(np.argmin(values))
    best = float(OFFSET_GRID[i])
    if 0 < i < len(values) - 1:
        best += _vertex_shift(values, i, float(OFFSET_GRID[1] - OFFSET_GRID[0]))
    zero = int(np.argmin(np.abs(OFFSET_GRID)))
    return OffsetScan(best, float(values[zero] - values[i]), rows.k.shape[0])


def fit_table(table: Table, options: FitOptions = FitOptions()) -> FitResult:
    """Validate ``table`` and fit the free parameters; see the module docstring.

    With the errors-in-variables model and the time offset neither fitted nor given, the
    fit then scans for one (:func:`offset_scan`) and, when the poses fit better at an
    offset by more than :data:`OFFSET_GAIN` nats, fits again with ``time_offset`` free;
    either way one note says what the scan found."""
    res = _fit_once(table, options)
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
        refit = _fit_once(table, replace(options, free=res.free + ("time_offset",)))
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


def _fit_once(table: Table, options: FitOptions) -> FitResult:
    """:func:`fit_table` without the time-offset scan."""
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
        if len(table) >= WORKER_ROWS:
            _get_worker()  # it starts (imports numpy) while this process prepares the rows
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
            sigma0 = _sigma0(at_p, free)
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
        like, res, extra = _core(rows, base, newton_free, options, notes, start, not searching, prev)
        n_evals += extra
        r_outer_se = float("nan")
        if "r_outer" in free and res.ok:
            params = to_params(base, newton_free, res.theta)
            like.choose_regimes(params)
            r_outer, r_outer_se, _f = _fit_r_outer(like, params, rows)
            base = replace(base, r_outer=r_outer)
            start = to_params(base, newton_free, res.theta)
            like, res, extra = _core(rows, base, newton_free, options, notes, start)
            n_evals += extra
        if not eiv or not res.ok:
            break
        start, prev = to_params(base, newton_free, res.theta), res
        new0 = _sigma0(start, free)
        if eiv_pass == 2 or all(abs(math.log(a / b)) < math.log(1.25) for a, b in zip(new0, sigma0)):
            if searching and rows.k.shape[0] > SUBSAMPLE and "time_offset" not in newton_free:
                like, res, extra = _full_stage(rows, base, newton_free, options, notes, res)
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
    lo_n, hi_n = _box(newton_free)
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
    lo, _hi = _box(newton_free)
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
                # estimate is an unevaluated Newton step from there (_full_stage, < 0.08
                # standard errors): the meat is centred (kappa_eq's and r_en's s.e. moved
                # by < 0.2 % on the 1e5-row pose-error benchmark's campaigns); so are the
                # differences of boundary_nuisance_cov (its points at theta +- h: memoised)
                at = res.evaluated
                at = at if at is not None and np.array_equal(at[active], theta_n[active]) else theta_n
                scores = _scores(like, base, newton_free, at, res.steps, live=keep)
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
    separable = _separable(ok, why, free, cov, estimate, se)
    if not separable:
        ok_line = (
            "pose error and EMI noise cannot be told apart with these rows "
            f"(no readings closer than {math.exp(float(np.percentile(rows.geo.log_r, 2))):.1f} m to the transmitter): "
            "r_en is not determined; walk closer or give --gps-sigma / --attitude-sigma"
        )
        notes.insert(0, ok_line)
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
        separable=separable,
        n_pose_dropped=n_dropped,
        stamps=stamps,
        n_evals_all_rows=res.full_evals or (n_evals if n <= SUBSAMPLE or "time_offset" in newton_free else 0),
    )


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
    logps = lambda ths: _logps(like, [to_params(base, free, th) for th in ths])  # noqa: E731 (one batch: :func:`_logps`)
    v0 = np.exp(2.0 * theta[floor])

    def at(th, dv):  # theta with the floor sigmas at sqrt(v0 + dv)
        out = th.copy()
        out[floor] = 0.5 * np.log(v0 + dv)
        return out

    start = {"gps_sigma": 0.5**2, "attitude_sigma": math.radians(1.0) ** 2}
    delta = np.array([0.25 * start[free[i]] for i in floor])
    for _attempt in range(2):
        pairs = [(a, b) for a in range(m) for b in range(a + 1, m)]
        got = logps([theta] + [at(theta, delta * np.eye(m)[a]) for a in range(m)]
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
    got = iter(logps(shifts))
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
        sample = sub, idx, scale = _height_sample(like)
        up = replace(base, height_offset=base.height_offset + HEIGHT_STEP)
        steps = [delta * np.eye(m)[a] for a in range(m)]
        got = _logps(sub, [to_params(up, free, th) for th in [theta] + [at(theta, d) for d in steps] + [at(theta, 2.0 * d) for d in steps]])
        l0, l1, l2 = got[0], got[1 : 1 + m], got[1 + m :]
        s_v_up = np.array([float(np.sum(-3.0 * l0 + 4.0 * l1[a] - l2[a])) / (2.0 * delta[a]) for a in range(m)])
        slope = np.concatenate([score_height_slope(like, base, free, theta, h, keep, scores_keep, sample),
                                scale * (s_v_up - s_v[idx].sum(axis=0)) / HEIGHT_STEP])
    inv = np.linalg.inv(big)
    meat, lag = time_block_meat(*with_common_height(scores, like.rows.t, height, slope))
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


def _height_sample(like: Likelihood):
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
    so kept cheap). ``sample``: :func:`_height_sample`'s result, when the caller has it."""
    sub, idx, scale = _height_sample(like) if sample is None else sample
    up = replace(base, height_offset=base.height_offset + HEIGHT_STEP)
    return scale * (_scores(sub, up, free, theta, h, live=cols).sum(axis=0) - np.sum(scores[idx], axis=0)) / HEIGHT_STEP


def with_common_height(scores, t, height, slope):
    """The scores and times for :func:`time_block_meat`, with the common height's influence
    rows w_i (dS/dh) appended when ``height`` (:func:`common_height_rows`) is given."""
    if height is None or slope is None:
        return scores, t
    w, t_rows = height
    return np.concatenate([scores, np.outer(w, slope)]), np.concatenate([np.asarray(t, dtype=np.float64), t_rows])


#: |correlation| of r_en with a pose-error sigma above which the two are not told apart.
SEPARATION_CORR = 0.9


def _separable(ok, why, free, cov, estimate, se) -> bool:
    """Whether the fit told pose error from EMI noise: r_en determined to within half
    its value and not almost a function of a fitted pose-error sigma. A fit that failed
    for another stated reason (r_en at its ceiling: no noise floor at all) is not blamed
    on the pose error."""
    if "r_en" not in free:
        return True
    pose = [m for m in ("gps_sigma", "attitude_sigma") if m in free]
    if not pose:
        return True
    if not ok:
        return "upper bound" in why
    i = free.index("r_en")
    for m in pose:
        j = free.index(m)
        if cov[i, i] > 0 and cov[j, j] > 0:
            if abs(cov[i, j]) / math.sqrt(cov[i, i] * cov[j, j]) > SEPARATION_CORR:
                return False
    return bool(se["r_en"] <= 0.5 * estimate["r_en"])


#: The longest stretch of seconds with no rows :func:`time_block_meat` keeps (s); a gap
#: longer than this is shortened to it.
MEAT_GAP = 3600


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
    t = np.asarray(t, dtype=np.float64)
    sec = np.floor(t - t.min()).astype(np.int64)
    if int(sec.max()) > MEAT_GAP:
        # seconds with nothing logged are zeros in the sums; a gap longer than MEAT_GAP is
        # shortened to it (it already separates its two sides beyond any bandwidth), so a
        # log with a day's pause costs no day of zeros
        seconds, at = np.unique(sec, return_inverse=True)
        sec = np.concatenate([[0], np.cumsum(np.minimum(np.diff(seconds), MEAT_GAP))])[at]
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
