"""Does the fitted model describe the data? Randomised PIT residuals and a goodness-of-fit
test that allows for pose errors correlated in time (issue 28, Build item 5).

**PIT values.** For row i with observed outcome d_i (cm; -1 "nothing heard") the fitted
model gives P(d = k) for every outcome, the marginal over the pose-error model that the
likelihood computes per row. With the outcomes ordered 0 < 1 < ... < 100 r_outer < -1
(-1 last: "farther than shown"), the randomised PIT value is

    u_i = P(d < d_i) + V_i P(d = d_i),   V_i uniform on [0, 1],

with the likelihood's gross-error floor in both terms (P' = (1 - g) P + g / n_out, the
floor spreading g evenly over the n_out = 100 r_outer + 2 outcomes). If the model is right
every u_i is uniform on [0, 1] whatever the row's geometry (Dunn and Smyth 1996), so the
normal scores z_i = Phi^-1(u_i) are standard normal: z > 0 is a reading farther than the
model's median, a -1 where the model expects a reading has z near +5.

**The test.** Rows are grouped by distance (the fit's geometry, m: bins of
:data:`BIN_EDGES`, a bin with fewer than :data:`MIN_BIN_ROWS` rows merged into its smaller
neighbour). In each bin three sums that have mean 0 under the model are formed:

* ``shift``: sum of z (readings systematically longer or shorter than predicted; both
  directions count);
* ``scatter``: sum of z^2 - 1 (more spread than the model allows; only an excess counts:
  exact data near the transmitter scatter less than the fit's smallest pose error, a
  harmless misfit);
* ``tails``: sum of 1{|z| > 2.576} - 0.01 (more rows in the outer 1 % than the model
  puts there; only an excess counts).

When the fit sees GPS error (gps_sigma above its floor) one more sum over all rows,
``center``: 1{|z| < 0.674} - 0.5 (only an excess): a Gaussian error fitted to heavy-tailed
GPS error is a compromise, too wide for most rows and too narrow for a few, so too many
scores fall in the model's central half.

The pose error is correlated over tens of seconds, so neighbouring rows' z are dependent
and the independent-rows variance of a sum is too small (a naive KS or chi-square test
over-rejects). Each sum's variance is the time-block (Newey-West) long-run variance of
:func:`covariance.time_block_meat`, the one the sandwich standard errors use, but never
below the independent-rows variance (n, 2n, 0.0099 n, n / 4); with exact poses (no
errors-in-variables model) rows are independent and that variance is used. Each sum over
the square root of its variance is a z statistic with a normal p-value.

Separately, the -1 rows the model gives less than :data:`UNEXPECTED_CENSORED` are
counted: their count X has mean E (the sum of those rows' P(d = -1)) under the model, and
P(X >= c) <= E / c (Markov's inequality, whatever the dependence between rows).

The campaign's p-value is a weighted Bonferroni one: ``center``, when tested, gets
:data:`CENTER_WEIGHT` of the level and the other statistics share the rest equally (p_j
times their number over the share). The model is said not to fit when it is below
:data:`ALPHA`; :meth:`GoodnessOfFit.note` then names the finding in words. Its false-alarm
and detection rates are measured on independent campaigns (docs/calibration.md, "Does the
model fit?"; ``tests/perf/gof_study.py``).

Cost: the PIT needs P(d < d_i), P(d = d_i) and P(d = -1) (for the -1 rows' PIT and the
expected count): three likelihood evaluations, on a seeded subsample of at most :data:`MAX_ROWS` rows (the test
on 1e5 rows would have more power than any campaign needs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr, ndtri

from .covariance import time_block_meat
from .likelihood import GROSS_ERROR, Likelihood, Params, Rows
from .params import BOUNDS

#: Distance bins of the test (m, by the fit's geometry); the last is open.
BIN_EDGES = (0.0, 5.0, 10.0, 15.0, 25.0, 35.0, math.inf)
#: A bin with fewer rows is merged into its smaller neighbour.
MIN_BIN_ROWS = 200
#: At most this many rows (a seeded subsample) go into the PIT test.
MAX_ROWS = 10000
#: The outer two-sided tail of the ``tails`` statistic.
TAIL = 0.01
TAIL_Z = float(ndtri(1.0 - TAIL / 2.0))
#: The test says the model does not fit below this (Bonferroni-adjusted) p-value.
ALPHA = 0.01
#: The central half of the model's distribution: |z| below this.
CENTER_Z = float(ndtri(0.75))
#: The share of ALPHA the ``center`` statistic gets when it is tested (weighted Bonferroni).
CENTER_WEIGHT = 0.5
#: Normal scores are clipped to +-Z_CAP (u within 1e-15 of 0 or 1).
Z_CAP = 8.0
#: A -1 row is "unexpected" when the model gives it less than this probability.
UNEXPECTED_CENSORED = 1e-3
#: The count of -1 rows the model gives less than UNEXPECTED_CENSORED (all bins).
JUNK = "unexpected_censored"
#: The statistics per bin; their independent-rows variance per row under the model.
FEATURES = ("shift", "scatter", "tails")
_VAR0 = (1.0, 2.0, TAIL * (1.0 - TAIL))


def pit_values(like: Likelihood, p: Params, v: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, P(d = -1)) per row of ``like`` under ``p``: the randomised PIT values
    u_i = P'(d < d_i) + v_i P'(d = d_i) (P' with the gross-error floor; see the module
    docstring), ``v`` uniform draws, one per row, and the model's probability of a -1
    (without the floor). Three likelihood evaluations."""
    k = like.k
    n_out = 100.0 * p.r_outer + 2.0
    prob = like.prob(p)  # P(d = d_i) without the floor
    p_cens = like.prob_censored(p)
    det = k != -1
    below = np.where(det, 0.0, 1.0 - p_cens)  # below a -1: every reading
    if det.any():
        shown = Likelihood(like.rows.take(det))
        shown.choose_regimes(p)
        below[det] = shown.prob_below(p)
    rank = np.where(det, np.maximum(k, 0).astype(np.float64), n_out - 1.0)  # outcomes below d_i
    g = GROSS_ERROR
    u = np.clip((1.0 - g) * (below + v * prob) + g * (rank + v) / n_out, 0.0, 1.0)
    return u, p_cens


def normal_scores(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Phi^-1(u), clipped to +-Z_CAP."""
    with np.errstate(divide="ignore"):
        return np.clip(ndtri(u), -Z_CAP, Z_CAP)


@dataclass
class BinCheck:
    """One distance bin of the test."""

    lo: float  # m
    hi: float  # m (inf: open)
    rows: int
    mean_z: float
    var_z: float
    tail_fraction: float  # rows with |z| > TAIL_Z (TAIL expected)
    unexpected_censored: int  # -1 rows the model gives less than UNEXPECTED_CENSORED
    z: dict[str, float]  # the statistic per feature

    def to_json(self) -> dict:
        return {
            "from_m": self.lo, "to_m": None if math.isinf(self.hi) else self.hi, "rows": self.rows,
            "mean_z": self.mean_z, "var_z": self.var_z, "tail_fraction": self.tail_fraction,
            "unexpected_censored": self.unexpected_censored, "statistics": dict(self.z),
        }  # fmt: skip


@dataclass
class GoodnessOfFit:
    """The PIT test of one fit (see the module docstring)."""

    p_value: float  # Bonferroni-adjusted
    fits: bool  # p_value >= ALPHA
    rows: int  # rows in the test
    lag_seconds: float  # the time-block bandwidth
    worst_bin: int  # index into bins of the smallest p-value
    worst_feature: str
    bins: list[BinCheck] = field(default_factory=list)
    unexpected_censored: int = 0  # over all tested rows
    expected_unexpected: float = 0.0  # the model's expected count of such -1 rows
    p_unexpected: float = 1.0  # the count's p-value (Markov's inequality), Bonferroni-adjusted like p_value
    tests: int = 1  # statistics the p-value is adjusted for
    center_fraction: float = float("nan")  # PIT scores in the model's central half (0.5 expected)
    center_z: float | None = None  # its statistic; None: not tested (no GPS error fitted)

    def to_json(self) -> dict:
        return {
            "test": "randomised PIT residuals by distance, time-block variances",
            "p_value": self.p_value,
            "alpha": ALPHA,
            "fits": self.fits,
            "rows": self.rows,
            "lag_seconds": self.lag_seconds,
            "worst": {"bin": self.worst_bin, "statistic": self.worst_feature},
            "statistics_tested": self.tests,
            "unexpected_censored": self.unexpected_censored,
            "unexpected_censored_p_value": self.p_unexpected,
            "center_fraction": self.center_fraction,
            "center_statistic": self.center_z,
            "unexpected_censored_expected": self.expected_unexpected,
            "bins": [b.to_json() for b in self.bins],
        }

    def note(self) -> str | None:
        """What does not fit, in words, with the likely causes; None when it fits."""
        if self.fits:
            return None
        test = f"PIT test p = {self.p_value:.2g}"
        if self.p_unexpected < ALPHA:  # the most specific finding first
            return (
                f"the model does not describe this walk: {self.unexpected_censored} rows say 'nothing heard' (d = -1) "
                f"where it gives that less than {100 * UNEXPECTED_CENSORED:g} % chance ({self.expected_unexpected:.2g} "
                f"expected; {test}): spurious -1 rows (a receiver or logger that drops readings), which the model "
                "lacks and which pull r_en low, or positions metres off at those moments (GPS jumps, multipath)"
            )
        if self.worst_feature == "center":
            return (
                f"the pose-error model does not describe this walk: most readings scatter less than the fitted GPS "
                f"error allows and some far more ({100 * self.center_fraction:.0f} % of the PIT scores in the model's "
                f"central half, 50 % expected; {test}): heavy-tailed GPS error (multipath, jumps of metres) that a "
                "Gaussian error cannot describe; gps_sigma is a compromise and the standard errors may be off"
            )
        b = self.bins[self.worst_bin]
        where = f"at {b.lo:g}-{b.hi:g} m" if math.isfinite(b.hi) else (f"beyond {b.lo:g} m" if b.lo > 0 else "at every distance")
        stat = b.z[self.worst_feature]
        if self.worst_feature == "shift":
            way = "longer" if stat > 0 else "shorter"
            return (
                f"the model does not describe this walk: readings {where} are {way} than it predicts "
                f"(mean PIT score {b.mean_z:+.2f}, {test}): look for a clock offset between the receiver and the "
                "pose logs (--fit time_offset), a mounting bias of the receiver or its GPS antenna, or a wrong height"
            )
        return (
            f"the pose-error model does not describe this walk: readings {where} scatter more than it allows "
            f"(variance of the PIT scores {b.var_z:.2f}, 1 expected; {100 * b.tail_fraction:.1f} % of them in the "
            f"model's outer {100 * TAIL:g} %; {test}): heavy-tailed GPS error (multipath, jumps of metres), or readings "
            "the model lacks; the standard errors may be too small"
        )

    def summary(self) -> str:
        verdict = "no misfit found" if self.fits else "THE MODEL DOES NOT FIT (see note)"
        return f"goodness of fit: PIT residuals by distance on {self.rows} rows, p = {self.p_value:.2g}: {verdict}"


def _bins(r: NDArray[np.float64]) -> list[tuple[float, float]]:
    """BIN_EDGES with bins of fewer than MIN_BIN_ROWS rows merged into their smaller neighbour
    (the emptiest first)."""
    edges = list(BIN_EDGES)
    counts = np.histogram(r, bins=np.array(edges[:-1] + [np.inf]))[0].tolist()
    while len(counts) > 1 and min(counts) < MIN_BIN_ROWS:
        i = int(np.argmin(counts))
        j = i + 1 if i == 0 else (i - 1 if i == len(counts) - 1 or counts[i - 1] <= counts[i + 1] else i + 1)
        lo, hi = min(i, j), max(i, j)
        counts[lo] += counts[hi]
        del counts[hi]
        del edges[hi]
    return list(zip(edges[:-1], edges[1:]))


@dataclass
class PitRows:
    """What :func:`pit_test` needs, per row of the (subsampled) rows the fit used."""

    u: NDArray[np.float64]  # randomised PIT values
    r: NDArray[np.float64]  # distance (m, the fit's geometry)
    t: NDArray[np.float64] | None  # time (s); None: rows independent (exact poses)
    censored: NDArray[np.bool_]
    p_censored: NDArray[np.float64]  # the model's P(d = -1)
    gps_seen: bool  # the fit sees GPS error (gps_sigma above its floor): test ``center``


def pit_rows(rows: Rows, p: Params, seed: int = 0) -> PitRows:
    """The PIT values of ``p`` on ``rows`` (those the fit used, with their pose-error
    moments), on a seeded subsample of at most MAX_ROWS."""
    n = rows.k.shape[0]
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x6F1F,)))
    idx = np.sort(rng.choice(n, MAX_ROWS, replace=False)) if n > MAX_ROWS else np.arange(n)
    sub = rows.take(idx)
    like = Likelihood(sub)
    like.choose_regimes(p)
    u, p_cens = pit_values(like, p, rng.random(idx.shape[0]))
    eiv = sub.moments is not None and (p.gps_sigma > 0.0 or p.attitude_sigma > 0.0)
    gps_seen = eiv and p.gps_sigma > 1.05 * BOUNDS["gps_sigma"][0]
    return PitRows(u, np.exp(sub.geo.log_r), sub.t if eiv else None, sub.k == -1, p_cens, gps_seen)


def goodness_of_fit(rows: Rows, p: Params, seed: int = 0) -> GoodnessOfFit | None:
    """The PIT test of ``p`` on ``rows`` (:func:`pit_rows`); None when there are fewer
    than MIN_BIN_ROWS rows. With the errors-in-variables model the variances are
    time-block ones (rows need time stamps); with exact poses the rows are independent."""
    if rows.k.shape[0] < MIN_BIN_ROWS:
        return None
    x = pit_rows(rows, p, seed)
    return pit_test(x.u, x.r, x.t, x.censored, x.p_censored, center=x.gps_seen)


def pit_test(u, r, t, censored, p_censored, center: bool = False) -> GoodnessOfFit:
    """The test of the module docstring from each row's PIT value ``u``, distance ``r``
    (m), time ``t`` (s; None: rows independent, as with exact poses), whether it is a -1
    and the model's P(d = -1); with ``center`` the ``center`` statistic too (a fit that
    sees GPS error)."""
    z = normal_scores(u)
    rare = p_censored < UNEXPECTED_CENSORED
    unexpected = censored & rare
    expected = float(np.sum(p_censored[rare]))

    bins = _bins(r)
    which = np.searchsorted(np.array([hi for _lo, hi in bins[:-1]]), r, side="right")
    tail = (np.abs(z) > TAIL_Z).astype(np.float64)
    per_row = (z, z * z - 1.0, tail - TAIL)
    cols = np.zeros((z.shape[0], len(bins) * len(FEATURES)))
    for b in range(len(bins)):
        sel = which == b
        for f, values in enumerate(per_row):
            cols[sel, b * len(FEATURES) + f] = values[sel]
    inside = (np.abs(z) < CENTER_Z).astype(np.float64)
    if center:
        cols = np.column_stack([cols, inside - 0.5])
    if t is None:
        meat, lag = np.zeros((cols.shape[1], cols.shape[1])), 0.0  # the independent-rows variances below
    else:
        meat, lag = time_block_meat(cols, t)
    sums = cols.sum(axis=0)
    checks: list[BinCheck] = []
    best = (2.0, 0, FEATURES[0])
    for b, (lo, hi) in enumerate(bins):
        sel = which == b
        nb = int(sel.sum())
        stats = {}
        for f, name in enumerate(FEATURES):
            j = b * len(FEATURES) + f
            var = max(float(meat[j, j]), _VAR0[f] * nb)
            stat = float(sums[j] / math.sqrt(var)) if var > 0 else 0.0
            stats[name] = stat
            p1 = 2.0 * float(ndtr(-abs(stat))) if name == "shift" else float(ndtr(-stat))
            if p1 < best[0]:
                best = (p1, b, name)
        zb = z[sel]
        checks.append(
            BinCheck(float(lo), float(hi), nb, float(zb.mean()), float(zb.var()), float(tail[sel].mean()),
                     int(unexpected[sel].sum()), stats)  # fmt: skip
        )
    # -1 rows the model gives less than UNEXPECTED_CENSORED: their count X has mean
    # `expected` under the model, and P(X >= c) <= expected / c (Markov's inequality, true
    # however the rows depend on each other)
    n_unexpected = int(unexpected.sum())
    p_junk = min(1.0, expected / n_unexpected) if n_unexpected else 1.0
    if p_junk < best[0]:
        best = (p_junk, int(np.bincount(which[unexpected], minlength=len(bins)).argmax()), JUNK)
    tests = len(bins) * len(FEATURES) + 1
    factor = tests / (1.0 - CENTER_WEIGHT if center else 1.0)
    p_value = min(1.0, best[0] * factor)
    center_z = None
    if center:  # all rows: most inside the central half, a few far out (a scale mixture)
        var = max(float(meat[-1, -1]), 0.25 * z.shape[0])
        center_z = float(sums[-1] / math.sqrt(var))
        p_center = min(1.0, float(ndtr(-center_z)) / CENTER_WEIGHT)
        if p_center < p_value:
            p_value, best = p_center, (p_center, best[1], "center")
        tests += 1
    return GoodnessOfFit(
        p_unexpected=min(1.0, p_junk * factor), tests=tests, center_fraction=float(inside.mean()), center_z=center_z,
        p_value=p_value, fits=p_value >= ALPHA, rows=int(z.shape[0]), lag_seconds=lag, worst_bin=best[1],
        worst_feature=best[2], bins=checks, unexpected_censored=int(unexpected.sum()), expected_unexpected=expected,
    )  # fmt: skip
