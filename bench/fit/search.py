"""Newton's method on the negative log-likelihood, in the optimiser's scale.

One projected, damped Newton method in the :data:`params.BOUNDS` box (:func:`newton`),
parametrised by what differs between the fit's searches: the gradient source
(:class:`Differences` of the likelihood, or :class:`Analytic`, one pass for exact poses)
and the curvature (the Hessian by differences at every iteration, or a Hessian carried
from a start and corrected by BFGS updates). Its pieces: difference gradients, the
eigenvalue-modified step, the active set (a parameter at a bound with the gradient
pointing out is held), bound probes, step caps, the line searches, and the objectives
(theta -> negative log-likelihood, nats).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .likelihood import LINEAR, Likelihood, Params, to_params
from .params import MAY_VANISH, box, caps, initial_steps
from .parallel import evaluate

#: Stop when the predicted gain to the optimum, g' H^-1 g / 2, is below this (nats):
#: the estimate is then within 0.005 standard errors of the optimum.
DECREMENT_TOL = 1e-5


def fd_gradient(f, theta, h, f0=None, hessian=False):
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
    values = evaluate(f, points)
    fp, fm = np.array(values[:p]), np.array(values[p : 2 * p])
    g = (fp - fm) / (2 * h)
    hess = np.diag((fp - 2 * f0 + fm) / h**2)
    for n, (i, j) in enumerate(pairs):
        fpp, fmm = values[2 * p + 2 * n : 2 * p + 2 * n + 2]
        v = fpp + fmm - fp[i] - fm[i] - fp[j] - fm[j] + 2 * f0
        hess[i, j] = hess[j, i] = v / (2 * h[i] * h[j])
    return g, hess


def forward_gradient(f, theta, h, f0, curvature):
    """Forward-difference gradient of f at theta with steps h (p evaluations instead of
    2p), its O(h) term h f''/2 taken off with ``curvature`` (the diagonal of a Hessian
    carried by the search, floored at 0): the error left is that Hessian's error times
    h/2 and O(h^2). Its points are :func:`fd_gradient`'s first p (the same floats, so a
    memoising likelihood keeps them for a later central stencil at theta)."""
    eye = np.diag(h)
    fp = np.array(evaluate(f, [theta + eye[i] for i in range(theta.shape[0])]))
    return (fp - f0) / h - 0.5 * np.maximum(curvature, 0.0) * h


def merge(theta, mask, values):
    out = theta.copy()
    out[mask] = values
    return out


def outward(theta, g, lo, hi):
    """Parameters at a bound whose gradient (of f, to be minimised) points outwards."""
    span = hi - lo
    return ((theta <= lo + 1e-9 * span) & (g > 0)) | ((theta >= hi - 1e-9 * span) & (g < 0))


def solve(hf, gf):
    """Newton step with the Hessian's eigenvalues replaced by their absolute values
    (floored at 1e-6 of the largest), so a saddle or a concave direction still gives a
    descent step of sensible length. Returns (step, modified?)."""
    w, v = np.linalg.eigh(0.5 * (hf + hf.T))
    if not np.all(np.isfinite(w)):
        return None, True
    top = float(np.max(np.abs(w))) if w.size else 1.0
    mod = np.maximum(np.abs(w), 1e-6 * top if top > 0 else 1e-12)
    return -(v @ ((v.T @ gf) / mod)), bool(np.any(w <= 0))


def decrement_of(g, stepf) -> float:
    """The Newton decrement g' H^-1 g / 2 of a step -H^-1 g: the predicted gain (nats)."""
    return -0.5 * float(g @ stepf)


def on_axes(p: int, idx, values) -> NDArray[np.float64]:
    """A vector of ``p`` zeros with ``values`` at ``idx`` (a step of the live parameters)."""
    out = np.zeros(p)
    out[idx] = values
    return out


def capped(step, cap, flat_ok=None) -> NDArray[np.float64]:
    """``step`` shortened so that no component exceeds its ``cap``. ``flat_ok``: parameters
    whose oversized component is clipped alone first (a pose-error sigma in a flat
    direction gets a huge Newton step; it should not shorten every other step with it),
    unless all oversized components are such."""
    step = step.copy()
    if flat_ok is not None:
        flat = flat_ok & (np.abs(step) > cap)
        if flat.any() and not flat.all():
            step[flat] = np.sign(step[flat]) * cap[flat]
    return step * min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))


def probe_bounds(value, theta, f0, step, lo, hi, cap, probe_lo, probe_hi):
    """A parameter heading for a bound where the likelihood flattens (pose_sigma with exact
    poses; r_en with no noise in the data) would creep there in capped steps: try the
    bound itself. ``probe_lo`` / ``probe_hi``: the parameters that may be tried at their
    lower / upper bound (r_en only when the step is capped or r_en is past 300 m).
    ``value(theta)`` returns a tuple whose first item is f. A bound is taken when f is
    lower there, or, at a lower bound, no more than 1e-6 higher (a sigma that no longer
    matters leaves f flat to rounding). Returns (theta, the last accepted value tuple or
    None, the indices taken)."""
    toward_lo = probe_lo & (step < 0) & (theta > lo)
    toward_hi = probe_hi & (step > 0) & ((np.abs(step) >= cap) | (theta > math.log(300.0))) & (theta < hi)
    got, taken = None, []
    for i in np.flatnonzero(toward_lo | toward_hi):
        trial = theta.copy()
        trial[i] = lo[i] if toward_lo[i] else hi[i]
        r = value(trial)
        if r[0] < f0 or (toward_lo[i] and r[0] < f0 + 1e-6):
            theta, f0, got = trial, r[0], r
            taken.append(int(i))
    return theta, got, taken


def bfgs(hk, s, y):
    """The BFGS update of the Hessian block ``hk`` from a step ``s`` and the gradient's
    change ``y``; None when the change has no positive curvature along the step."""
    ys, hs = float(y @ s), hk @ s
    shs = float(s @ hs)
    if ys > 1e-12 * max(shs, 1e-300) and shs > 0:
        return hk + np.outer(y, y) / ys - np.outer(hs, hs) / shs
    return None


def inside_step(theta, keep, stepf, lo, hi):
    """theta + the step of the ``keep`` parameters, or None when it leaves the box."""
    end = theta.copy()
    end[keep] += stepf
    return end if np.all((end >= lo) & (end <= hi)) else None


def with_placeholders(hl, held) -> NDArray[np.float64]:
    """The full Hessian from the block of the live (not ``held``) parameters; held ones get
    1 on the diagonal, a placeholder never used for a step."""
    p = held.shape[0]
    hess = np.zeros((p, p))
    live = np.flatnonzero(~held)
    hess[np.ix_(live, live)] = hl
    if held.any():
        hess[held, held] = 1.0
    return hess


def se_clipped(se, free, idx) -> NDArray[np.float64]:
    """Difference steps of 0.3 standard errors ``se`` for the parameters ``idx``, between 1e-7
    and 0.05 (0.5 for the linear ones, in s or m)."""
    top = np.where(np.isin(np.array(free)[idx], LINEAR), 0.5, 0.05)
    return np.clip(0.3 * se, 1e-7, top)


def line_search(f, theta, step, f0, lo, hi, cap=None):
    """Backtracking from the full step; if the full step already decreases f, keep
    doubling it while f keeps decreasing (the likelihood is steeper on the barrier side
    of r_en than a quadratic, so Newton steps from there fall short). The full and the
    first doubled step are evaluated together (two threads), which is what a step that
    lands usually costs; the search itself is unchanged. Returns (theta, f) or (None, f0).
    (Searches with a carried Hessian backtrack without doubling: :func:`backtrack`.)"""
    trial = np.clip(theta + step, lo, hi)
    longer = step * 2.0
    if cap is None or not np.any(np.abs(longer) > cap):
        t2 = np.clip(theta + longer, lo, hi)
        f1, f2 = evaluate(f, [trial, t2])
    else:
        f1, f2 = f(trial), None
    if f1 < f0:
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
class NewtonResult:
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
    #: from there that was not evaluated (:func:`full_stage`); else None
    evaluated: NDArray[np.float64] | None = None


def probes(free) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The parameters :func:`probe_bounds` may try at their lower bound (the sigmas of
    :data:`params.MAY_VANISH`) and at their upper bound (r_en)."""
    return np.array([n in MAY_VANISH for n in free]), np.array([n == "r_en" for n in free])


# -- the likelihood as an objective ----------------------------------------------------------


class Objective:
    """theta -> negative log-likelihood, for fixed regimes."""

    def __init__(self, like: Likelihood, base: Params, free: tuple[str, ...]) -> None:
        self.like, self.base, self.free = like, base, free

    def params(self, theta) -> Params:
        return to_params(self.base, self.free, theta)

    def __call__(self, theta) -> float:
        return self.like.nll(self.params(theta))


class Part:
    """``obj`` as a function of some of the coordinates (``full`` completes them to theta);
    with ``like`` and ``params`` as an :class:`Objective` has, so that :func:`evaluate`
    can hand its points to the worker process."""

    def __init__(self, obj, full) -> None:
        self.obj, self.full = obj, full
        self.like = obj.like if isinstance(obj, Objective) else None

    def params(self, x) -> Params:
        return self.obj.params(self.full(x))

    def __call__(self, x) -> float:
        return self.obj(self.full(x))


class GradObjective(Objective):
    """:class:`Objective` that also gives the gradient and the per-row scores (N, p) of
    log P from one pass (:meth:`Likelihood.logp_grad`)."""

    def __init__(self, like: Likelihood, base: Params, free: tuple[str, ...]) -> None:
        super().__init__(like, base, free)
        self.cols = [Likelihood.GRAD_PARAMS.index(n) for n in free]

    def value_grad(self, theta):
        logp, d = self.like.logp_grad(to_params(self.base, self.free, theta))
        scores = d[self.cols].T
        return -float(np.sum(logp)), -scores.sum(axis=0), scores


#: Parameters whose column of the all-rows Hessian :func:`hessian_fd` takes by a forward
#: difference (one pass instead of two): with 3e4-1e5 rows kappa_eq's curvature is smooth
#: (its entry moves by < 1e-5 between steps of 0.1 and 1 s.e.; s.e. unchanged to 1e-4),
#: unlike r_en's. Not below SUBSAMPLE rows: on 1200 rows it moved kappa_eq's s.e. by 2.3 %.
ONE_SIDED = ("kappa_eq",)


def hessian_fd(obj: GradObjective, theta, g0, live, h, lo, hi, one_sided=()):
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
    grads = iter(evaluate(lambda th: obj.value_grad(th)[1], points))
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


def se_steps(hl, free, live, fallback):
    """Difference steps of 0.3 standard errors from a live-parameter Hessian."""
    steps = fallback.copy()
    try:
        se = np.sqrt(np.maximum(np.diag(np.linalg.inv(hl)), 1e-18))
    except np.linalg.LinAlgError:
        return steps
    top = np.where(np.isin(np.array(free)[live], LINEAR), 0.5, 0.05)
    steps[live] = np.clip(0.3 * se, 1e-7, top)
    return np.where(np.isfinite(steps), steps, fallback)


# -- one Newton search, two gradient sources ---------------------------------------------------


class Differences:
    """Gradient source of a search on ``f`` (an :class:`Objective`: theta -> nats) by central
    differences with the search's steps h: 2p evaluations for the gradient, p^2 + p for
    the Hessian too (:func:`fd_gradient`; its axis points are the gradient's, which a
    memoising likelihood keeps). No per-row scores."""

    scores = False

    def __init__(self, f, forward: bool = False) -> None:
        self.f = f
        #: The gradients of a BFGS search's steps by forward differences
        #: (:meth:`step_gradient`); its ends (the Hessian by differences) stay central.
        self.forward = forward

    def value(self, theta) -> tuple[float]:
        return (self.f(theta),)

    def gradient(self, theta, f0, mask, h, hessian=False):
        """The gradient of the coordinates ``mask`` at ``theta`` (and their Hessian)."""
        return fd_gradient(Part(self.f, lambda x: merge(theta, mask, x)), theta[mask], h[mask], f0, hessian)

    def step_gradient(self, theta, f0, mask, h, curvature):
        """The gradient of ``mask`` at a point of a BFGS search: central differences, or
        with :attr:`forward` forward ones corrected by ``curvature``, the diagonal of the
        carried Hessian of ``mask`` (:func:`forward_gradient`)."""
        if not self.forward:
            return self.gradient(theta, f0, mask, h)[0]
        return forward_gradient(Part(self.f, lambda x: merge(theta, mask, x)), theta[mask], h[mask], f0, curvature)

    def renewed(self, theta, f0, g, keep, hk, h, lo, hi, free):
        """(Hessian of the ``keep`` parameters by differences of f, the same steps, and
        with :attr:`forward` their central gradient from the same points, else None)."""
        mask = np.zeros(len(free), bool)
        mask[keep] = True
        g_c, hess = self.gradient(theta, f0, mask, h, hessian=True)
        return hess, h, (g_c if self.forward else None)


class Analytic:
    """Gradient source of a search on a :class:`GradObjective`: one pass gives f, the gradient
    and the per-row scores (whose outer product, BHHH, is a curvature to start from); the
    Hessian by central differences of the gradient, steps re-set to 0.3 standard errors
    (:func:`hessian_fd`; ``one_sided``: its forward-difference columns)."""

    scores = True

    def __init__(self, obj: GradObjective, one_sided=()) -> None:
        self.obj, self.one_sided = obj, one_sided

    def value(self, theta):
        return self.obj.value_grad(theta)

    def renewed(self, theta, f0, g, keep, hk, h, lo, hi, free):
        h = se_steps(hk, free, keep, h)
        return hessian_fd(self.obj, theta, g, keep, h, lo, hi, self.one_sided), h, None


#: With the outer product of the scores as curvature, the search takes the Hessian by
#: differences after BHHH_STEPS steps (or two in a row that do not halve the decrement).
BHHH_STEPS = 4
NOT_FINITE = "the likelihood is not finite next to the estimate"


def newton(
    source, theta, free, max_iter, tol=DECREMENT_TOL, *, recompute=False, h=None, held=None, hess0=None,
    hessian="final", finish=None, probe=True, near=0.0,
) -> NewtonResult:
    """Projected, damped Newton on f (the negative log-likelihood) in the BOUNDS box.

    What differs between the fit's searches is the two parameters:

    * ``source``: :class:`Differences` (the errors-in-variables likelihood) or
      :class:`Analytic` (exact poses: the gradient from one pass);
    * ``recompute``: the Hessian by differences at every iteration (the search from a
      pilot: difference steps start at ``h`` and are re-set to 0.3 standard errors from
      each Hessian; convergence needs a decrement below ``tol`` with steps that no longer
      change by more than a factor 2), or else a Hessian carried from a start and
      corrected by BFGS updates from the gradient's changes: ``hess0`` (a previous one,
      e.g. a subsample's scaled), the outer product of the scores (Analytic; replaced by
      the Hessian by differences after BHHH_STEPS steps or two slow ones) or the Hessian
      by differences (Differences). ``hessian``: "final", the Hessian by differences at
      the estimate; "some" (Analytic): one taken anywhere on the way; "none": whatever
      curvature was used (a pre-pass). ``finish`` (with "final"; a decrement above
      ``tol``): once the decrement is below it, the Hessian by differences is taken where
      the search stands and one Newton step with it, not evaluated, ends the search (its
      f is the quadratic model's; ``evaluated`` says where the last gradient was taken).
      A :class:`Differences` source with ``forward`` (BFGS, with ``finish``) takes its
      steps' gradients by forward differences; its decrement is not trusted to converge
      on, so below ``finish`` it always finishes, with the gradient central from the
      Hessian's stencil: where it stands when the decrement is below ``near`` (the
      forward points are the stencil's), else where the quasi-Newton step lands when f
      is lower there (one value: the Hessian nearer the optimum).

    The active set: a parameter at a bound whose gradient points out is held there. Where
    the gradient of every parameter is known at each iteration (recompute, or Analytic)
    the set is re-checked each time; a BFGS search by differences keeps its ``held`` set
    and evaluates only the others. A parameter heading for a bound where f flattens (a
    pose-error sigma toward its floor, r_en toward its ceiling) is tried at the bound
    (:func:`probe_bounds`); a BFGS search by differences tries each sigma once (with
    ``probe``) and holds it there.

    The fit uses three combinations (:mod:`.stages`): Differences with ``recompute`` from
    a pilot (the errors-in-variables passes), Differences with BFGS from a previous
    Hessian (a warm pass, and the steps on all rows of a big table), and Analytic with
    BFGS from the outer product or a subsample's Hessian (exact poses). Each iteration:
    where the search stands (gradient, curvature, active set), whether it has converged
    or needs a better curvature first (recompute: difference steps re-set or shrunk;
    BFGS: the Hessian by differences when stalled, wanted at the end, or to finish), then
    a step (a bound tried first, else the capped Newton step with a line search: doubling
    with recompute, backtracking otherwise) and the BFGS update."""
    p = len(free)
    lo, hi = box(free)
    cap = caps(free)
    fd = not source.scores
    recheck = recompute or not fd  # the gradient of every parameter at each iteration
    h = initial_steps(free) if h is None else h.copy()
    probe_lo, probe_hi = probes(free)
    if not recheck:
        probe_lo, probe_hi = probe_lo & probe, np.zeros(p, bool)
    probed = np.zeros(p, bool)
    theta = np.clip(theta, lo, hi)
    none = np.zeros(p, bool)
    if recompute:
        f0 = source.value(theta)[0]
        g = scores = None
    elif fd:
        f0, g, scores = source.value(theta)[0], np.zeros(p), None
    else:
        f0, g, scores = source.value(theta)
    if recheck and not math.isfinite(f0):
        return NewtonResult(theta, f0, None, none, h, 0, False, "the likelihood is zero at the starting point")
    held = np.zeros(p, bool) if held is None else held.copy()
    hq = np.eye(p) if hess0 is None else hess0.copy()  # the carried curvature (all parameters)
    exact_at = None  # (theta, live parameters) where hq is the Hessian by differences
    differenced = hess0 is not None and hessian != "final"  # a Hessian taken somewhere (for "some")
    bhhh = hess0 is None and not fd  # the outer product at each point, until a Hessian is differenced
    n_steps, last_dec, shrinks = 0, math.inf, 0
    ok, why = False, f"no convergence after {max_iter} Newton iterations"

    def difference(theta, keep, hk):
        """The Hessian by differences where the search stands."""
        nonlocal h, bhhh, exact_at, differenced, n_steps, last_dec
        if not fd:
            n_steps, last_dec = 0, math.inf
        hq[np.ix_(keep, keep)], h, central = source.renewed(theta, f0, g, keep, hk, h, lo, hi, free)
        if central is not None:  # (forward-difference steps: the end's gradient is central)
            g[keep] = central
        bhhh, differenced, exact_at = False, True, (theta.copy(), keep)
        return hq[np.ix_(keep, keep)]

    if not recompute and fd:  # the start: the gradient of the live parameters, and a curvature
        keep = np.flatnonzero(~held)
        if hess0 is None:
            g[keep], hq[np.ix_(keep, keep)] = source.gradient(theta, f0, ~held, h, hessian=True)
            exact_at = (theta.copy(), keep)
        else:
            g[keep] = source.step_gradient(theta, f0, ~held, h, np.diag(hq)[keep])
    it = 0
    for it in range(1, max_iter + 1):
        # -- where the search stands: gradient, curvature and the active set
        if recompute:
            g = np.zeros(p)
            if held.any():
                g[held] = source.gradient(theta, f0, held, h)[0]
            gl, hl = source.gradient(theta, f0, ~held, h, hessian=True)
            g[~held] = gl
            hq = with_placeholders(hl, held)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(hq))):
                return NewtonResult(theta, f0, hq, none, h, it, False, NOT_FINITE)
        elif not fd and not (math.isfinite(f0) and np.all(np.isfinite(g))):
            return NewtonResult(theta, f0, hq, none, h, it, False, NOT_FINITE)
        active = outward(theta, g, lo, hi) if recheck else held
        keep = np.flatnonzero(~active)
        if recompute:
            if np.any(active & ~held):
                held = active.copy()
                continue  # recompute without the held rows (cheaper, and exact for the rest)
            held = active.copy()
        elif not fd and keep.size == 0:
            return NewtonResult(theta, f0, np.eye(p), active, h, it, True, "converged")
        if bhhh:
            hq[np.ix_(keep, keep)] = scores[:, keep].T @ scores[:, keep]
        hk = hq[np.ix_(keep, keep)]
        stepf, modified = solve(hk, g[keep])
        if stepf is None:
            if not fd or recompute:
                return NewtonResult(theta, f0, hq, active, h, it, False, "the Hessian is not finite")
            break
        decrement = decrement_of(g[keep], stepf)
        # -- converged, or a better curvature first
        if recompute:
            if tol >= 0.5 and decrement < tol:
                # The pre-pass only settles the likelihood regimes: close enough, whatever the
                # curvature at these steps (the next pass looks closer).
                return NewtonResult(theta, f0, hq, active, h, it, True, "converged")
            if modified and decrement < 0.5 and shrinks < 3:
                # Not convex at this step size. Either a difference straddles a steep side (the
                # noise edge: look again with smaller steps) or a flat, curved direction (a
                # pose-error sigma far from its estimate): try the (modified) step first, and
                # keep it if it clearly lowers f.
                trial = np.clip(theta + capped(on_axes(p, keep, stepf), cap), lo, hi)
                f1 = source.value(trial)[0]
                if f1 < f0 - 1e-3:
                    theta, f0 = trial, f1
                    continue
                shrinks += 1
                h = h / 3.0
                continue
            new_h = h.copy()
            if not modified:
                w, v = np.linalg.eigh(0.5 * (hk + hk.T))
                new_h[keep] = se_clipped(np.sqrt(np.maximum((v * v) @ (1.0 / np.maximum(w, 1e-300)), 0.0)), free, keep)
            if not modified and decrement < tol:
                if tol > DECREMENT_TOL or np.all(np.abs(np.log(new_h / h)) < math.log(2.0)):
                    return NewtonResult(theta, f0, hq, active, h, it, True, "converged")
                h = new_h  # once more, with steps on the standard-error scale
                continue
            h = new_h
        else:
            here = exact_at is not None and np.array_equal(exact_at[0], theta) and np.array_equal(exact_at[1], keep)
            if fd:
                stalled = want = False
                # (a forward gradient's decrement is not trusted below tol: it finishes too)
                floor = 0.0 if source.forward else tol
                finishing = finish is not None and hessian == "final" and floor <= decrement < finish and not here
            else:
                slow = n_steps >= 2 and decrement > 0.5 * last_dec
                stalled = decrement >= tol and ((bhhh and n_steps >= BHHH_STEPS) or slow)
                want = (hessian == "final" and not here) or (hessian == "some" and not differenced)
                finishing = finish is not None and hessian == "final" and decrement < finish and not here
            if stalled or (decrement < tol and want) or finishing:
                if finishing and fd and source.forward and not modified and decrement >= near:
                    # the end's stencil where the quasi-Newton step lands when f is lower there
                    # (one value): the Hessian nearer the optimum than from where it was taken
                    ahead = inside_step(theta, keep, stepf, lo, hi)
                    f_ahead = math.inf if ahead is None else source.value(ahead)[0]
                    if f_ahead <= f0:
                        theta, f0 = ahead, f_ahead
                hk = difference(theta, keep, hk)
                stepf, modified = solve(hk, g[keep])
                if stepf is None:
                    if not fd:
                        return NewtonResult(theta, f0, hq, active, h, it, False, "the Hessian is not finite")
                    break
                decrement = decrement_of(g[keep], stepf)
                end = inside_step(theta, keep, stepf, lo, hi) if finishing and decrement < finish else None
                if end is not None and not (fd and modified):
                    hess = with_placeholders(hk, held) if fd else hq
                    out = NewtonResult(end, f0 - decrement, hess, active, h, it, True, "converged")
                    out.evaluated = theta  # (where the last gradient and that Hessian were taken)
                    return out
            n_steps += 1
            last_dec = decrement
            if decrement < tol:
                if fd:
                    ok = True
                    break
                return NewtonResult(theta, f0, hq if differenced else None, active, h, it, True, "converged")
        # -- a step: a bound tried first, then the (capped) Newton step with a line search
        step = on_axes(p, keep, stepf)
        lo_ok = probe_lo
        if not recheck:  # each sigma once
            lo_ok = probe_lo & ~held & ~probed
            probed |= lo_ok & (step < 0) & (theta > lo)
        theta, got, taken = probe_bounds(source.value, theta, f0, step, lo, hi, cap, lo_ok, probe_hi)
        if got is not None:
            n_steps, last_dec = 0, math.inf
            if recompute:
                f0 = got[0]
            elif fd:
                f0 = got[0]
                held[taken] = True  # (this search keeps its active set: held at the bound)
                g[~held] = source.step_gradient(theta, f0, ~held, h, np.diag(hq)[~held])
            else:
                f0, g, scores = got
            continue
        step = capped(step, cap, probe_lo if recheck else None)
        if recompute:
            trial, f1 = line_search(source.f, theta, step, f0, lo, hi, cap)
            if trial is None:
                # Near a steep side (the noise edge) differences over 0.3 standard errors bias
                # the gradient: retry with a gradient from steps ten times smaller.
                gk = source.gradient(theta, f0, ~active, h / 10.0)[0]
                stepf, _mod = solve(hk, gk)
                decrement = decrement_of(gk, stepf)
                step = capped(on_axes(p, keep, stepf), cap)
                trial, f1 = line_search(source.f, theta, step, f0, lo, hi, cap) if decrement >= tol else (None, f0)
            if trial is None:
                if not modified and decrement < 1e-3:
                    return NewtonResult(theta, f0, hq, active, h, it, True, "converged")
                if shrinks < 4:  # the differences were too coarse here: look closer
                    shrinks += 1
                    h = h / 3.0
                    continue
                return NewtonResult(theta, f0, hq, active, h, it, False, "no step decreases the negative log-likelihood")
            theta, f0 = trial, f1
            continue
        trial, r = backtrack(source.value, theta, step, f0, lo, hi)
        if trial is None:
            if fd:  # from a good start: no step gains, the search is there
                ok = True
                break
            if exact_at is not None and decrement < 1e-3:
                return NewtonResult(theta, f0, hq, active, h, it, True, "converged")
            return NewtonResult(theta, f0, hq, active, h, it, False, "no step decreases the negative log-likelihood")
        if fd:
            g1 = g.copy()
            g1[keep] = source.step_gradient(trial, r[0], ~held, h, np.diag(hq)[keep])
            r = (r[0], g1, None)
        else:
            trial, r = secant(source.value, theta, trial, g, r, lo, hi)
        f1, g1, s1 = r
        updated = None if bhhh else bfgs(hk, (trial - theta)[keep], (g1 - g)[keep])  # on the live block
        if updated is not None:
            hq[np.ix_(keep, keep)] = updated
        theta, f0, g, scores = trial, f1, g1, s1
    if recheck:
        return NewtonResult(theta, f0, hq, none, h, max_iter, False, why)
    # a BFGS search by differences ends with the Hessian by differences where it stands
    keep = np.flatnonzero(~held)
    if not (exact_at is not None and np.array_equal(exact_at[0], theta) and np.array_equal(exact_at[1], keep)):
        difference(theta, keep, hq[np.ix_(keep, keep)])
    why = "converged" if ok else "no convergence of the quasi-Newton search"
    return NewtonResult(theta, f0, with_placeholders(hq[np.ix_(keep, keep)], held), held, h, it, ok, why)


def backtrack(value, theta, step, f0, lo, hi):
    """The full step, then halving it up to 11 times, until f decreases: (trial, value
    tuple) or (None, None)."""
    for _half in range(12):
        trial = np.clip(theta + step, lo, hi)
        r = value(trial)
        if r[0] < f0:
            return trial, r
        step = step * 0.5
    return None, None


def secant(value, theta, trial, g, r, lo, hi):
    """When the accepted point lies far past the minimum along the step (the slope there
    points back more than half as steeply as it fell: the curvature underestimated, as the
    outer product does on the steep side of r_en), the secant of the slope: (that point,
    its value tuple) if f is lower there, else (``trial``, ``r``)."""
    g1 = r[1]
    d0, d1 = float(g @ (trial - theta)), float(g1 @ (trial - theta))
    if d0 < 0 < d1 and d1 > -0.5 * d0:
        alt = np.clip(theta + (trial - theta) * (d0 / (d0 - d1)), lo, hi)
        r2 = value(alt)
        if r2[0] < r[0]:
            return alt, r2
    return trial, r
