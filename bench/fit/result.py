"""What a fit is asked (:class:`FitOptions`) and what it gives (:class:`FitResult`).

Estimates in natural units (kappa_eq for s = 1, lengths in m, sigmas in m and rad, the
offset in s); standard errors by the delta method from the optimiser's scale (logs of
the positive parameters); ``cov_theta`` on that scale. :meth:`FitResult.to_json` is the
object ``arva-bench fit --json`` prints (no NaN: missing values are null).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .diagnostics import GoodnessOfFit
from .likelihood import Likelihood, Params
from .table import TimeStamps

MAX_ITER = 60
#: What ``arva-bench fit`` estimates by default: GPS and attitude error from the data
#: (pose_sigma then stays at its 0.1 % floor, which keeps the ball's edge smooth).
EIV_FREE = ("kappa_eq", "r_en", "gps_sigma", "attitude_sigma")


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
    #: When the goodness-of-fit check finds spurious -1 rows (``estimate.dropout_if_spurious``),
    #: fit again with ``dropout`` free; False: keep the fit without it (the check's note stays)
    spurious_refit: bool = True
    #: Where the search starts, skipping the pilot (a restart: :func:`estimate.fit_restarted`); None: the pilot's
    start: Params | None = None
    #: The Newton decrement (nats) at which the search on up to stages.SUBSAMPLE rows
    #: stops; None: search.DECREMENT_TOL (a restart: estimate.RESTART_TOL)
    tol: float | None = None


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
    goodness_of_fit: GoodnessOfFit | None = None  # the PIT test (converged fits with time stamps)

    def add_cost(self, other: "FitResult") -> None:
        """Count ``other``'s time and likelihood evaluations in this result's (a fit that
        replaces, or was tried beside, ``other``)."""
        self.seconds += other.seconds
        self.n_evals += other.n_evals

    def to_json(self) -> dict:
        out: dict = {"source": self.source}
        for name in ("kappa_eq", "r_en", "r_outer", "pose_sigma", "time_offset", "gps_sigma", "attitude_sigma", "height_offset", "dropout"):
            out[name] = getattr(self.params, name)
            if name in self.free:
                out[f"{name}_se"] = self.se.get(name)
        for name in ("gps_outlier", "gps_outlier_scale", "mount_pitch", "mount_roll"):  # optional: only when used
            if name in self.free or (name == "gps_outlier_scale" and "gps_outlier" in self.free):
                out[name] = getattr(self.params, name)
                out[f"{name}_se"] = self.se.get(name) if name in self.free else None
        if not self.separable:  # r_en not determined: no number (docs/calibration.md, identifiability)
            out["r_en"] = out["r_en_se"] = None
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
            goodness_of_fit=None if self.goodness_of_fit is None else self.goodness_of_fit.to_json(),
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
