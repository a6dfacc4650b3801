"""Which parameters a campaign determines (issue 28, item 1): r_en against the GPS error.

With pose error, a reading's distance scatters for two reasons: the receiver's position
error (relative size gps_sigma / r, m over m) and the EMI noise (relative size
(r / r_en)^3: the noise field is constant, the transmitter's falls as r^-3). Only rows
where the second is at least the first tell r_en apart from the pose error; a walk
without enough of them (held to 5-15 m) leaves r_en to the pose-error model, which
then fitted r_en 2.5-4.4x too large with tight intervals (issue 28). The rule is
geometric, on the rows' distances at the estimate, not on the covariance: those fits'
covariances looked confident. At a too-large r_en fewer rows qualify, so the rule errs
towards "not determined"; at a too-small one more rows qualify, so the rule is evaluated
at r_en no lower than a typical receiver's (:data:`R_EN_TYPICAL`): on walks held to 5-15 m
the fit had put r_en 45-65 % low with intervals 6-8 s.e. wide of the truth, and at that
low value 530-1,114 rows counted (the study's near-only walk, 3 of 50 report fits;
`tests/bench/fit/test_fit_identify.py`). Distances in m (receiver to transmitter at the
expected true pose, up to r_outer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .likelihood import Params, Rows

#: r_en is determined when at least this fraction of the rows within r_outer ...
MIN_NOISE_FRACTION = 0.02
#: ... and at least this many rows have the EMI noise at least the GPS error.
MIN_NOISE_ROWS = 30
#: The lowest r_en (m) the rule is evaluated at: the receiver model's default (BRIEF 3,
#: r_en = 80 m). A walk that determines a lower r_en must then reach farther out than the
#: fitted value alone would ask; that errs towards "not determined", never to a wrong r_en.
R_EN_TYPICAL = Params().r_en


@dataclass(frozen=True)
class NoiseReach:
    """The rows where EMI noise shows through the GPS error (see the module docstring)."""

    rows: int  # rows within r_outer where (r / r_en)^3 >= gps_sigma / r
    within: int  # rows within r_outer
    r_cross: float  # the distance where the two are equal (m): (gps_sigma r_en^3)^(1/4)
    r_max: float  # the farthest row within r_outer (m)
    fitted: float = math.inf  # the fitted r_en (m), when lower than the R_EN_TYPICAL the rule used

    @property
    def determined(self) -> bool:
        return self.rows >= MIN_NOISE_ROWS and self.rows >= MIN_NOISE_FRACTION * self.within

    def note(self) -> str:
        at = "the fitted r_en" if self.fitted == math.inf else (
            f"r_en {R_EN_TYPICAL:g} m (a typical receiver's: the fitted {self.fitted:.0f} m is lower, and a walk "
            "that cannot place r_en can put it low)"
        )
        return (
            f"r_en is not determined: EMI noise and GPS error cannot be told apart with these rows (only {self.rows} of "
            f"{self.within} rows lie where the EMI noise, at {at}, would show through {self.gps:.2g} m of "
            f"GPS error: beyond about {self.r_cross:.0f} m; the farthest row is at {self.r_max:.0f} m); walk out beyond "
            f"{self.r_cross:.0f} m, or give the GPS error (--gps-sigma / --gps-grade) if it is better than that"
        )

    gps: float = 0.0  # the GPS error the rule used (m)


def noise_shows(r: NDArray[np.float64], r_en: float, gps: float) -> NDArray[np.bool_]:
    """Rows at distances ``r`` (m) where the EMI noise, (r / r_en)^3, is at least the GPS
    error, gps / r."""
    return (r / r_en) ** 3 >= gps / np.maximum(r, 1e-9)


def noise_reach(rows: Rows, p: Params, floor: float = R_EN_TYPICAL) -> NoiseReach:
    """:class:`NoiseReach` of ``rows`` at ``p`` (its gps_sigma, r_outer and r_en, or
    ``floor`` when that is larger)."""
    r = np.exp(rows.geo.log_r)
    r = r[np.isfinite(r) & (r <= p.r_outer)]
    gps = p.gps_sigma
    r_en = max(p.r_en, floor)
    shows = noise_shows(r, r_en, gps)
    return NoiseReach(
        rows=int(np.sum(shows)),
        within=int(r.shape[0]),
        r_cross=float((gps * r_en**3) ** 0.25),
        r_max=float(r.max()) if r.size else 0.0,
        fitted=p.r_en if p.r_en < floor else math.inf,
        gps=gps,
    )
