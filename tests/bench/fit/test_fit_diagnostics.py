"""The fit's goodness-of-fit check (bench/fit/diagnostics.py; issue 28, Build item 5):
randomised PIT values of the observed integers, the binned test with its exact statistics
on constructed scores, the note on campaigns of the independent generator (quiet when the
model describes them, firing on spurious -1 rows), and the JSON fields."""

import json
import math
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import norm
import repo_paths

sys.path.insert(0, str(repo_paths.PERF))

import study_campaigns as sc  # noqa: E402

from bench.fit import EIV_FREE, FitOptions, fit  # noqa: E402
from bench.fit import diagnostics as dg  # noqa: E402
from bench.fit.cli import summary  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.report import write_report  # noqa: E402
from bench.fit.likelihood import GROSS_ERROR, Likelihood, Params, rows_from_table  # noqa: E402

MISFIT_WORDS = "does not describe this walk"


def campaign_table(walk: str, error: str, junk: tuple[str, ...], seed: int, minutes: float = 20.0):
    camp = sc.campaign(sc.Condition("t", walk, error, junk, minutes=minutes), seed)
    return parse_csv(camp.csv_text(), f"{walk}-{error}-{seed}.csv"), camp


# -- the PIT values of a known discrete distribution --------------------------------------


def test_pit_values_are_the_cumulative_probabilities_of_the_ordered_outcomes():
    """u = P'(d < d_i) + v P'(d = d_i), outcomes ordered 0 < 1 < ... < 100 r_outer < -1, P' the
    likelihood's floor-mixed probabilities: checked against the sum of P(d = j) over every
    outcome j below the observed one, evaluated one outcome at a time."""
    table, _ = campaign_table("radial", "exact", (), 3)
    rows = rows_from_table(table)
    p = Params(kappa_eq=1.5, r_en=80.0, pose_sigma=0.01)
    pick = [int(np.flatnonzero((rows.k > 300) & (rows.k < 1500))[0]), int(np.flatnonzero((rows.k > 0) & (rows.k < 290))[0]),
            int(np.flatnonzero(rows.k == -1)[0])]  # fmt: skip
    sub = rows.take(np.array(pick))
    like = Likelihood(sub)
    like.choose_regimes(p)
    u0, p_cens = dg.pit_values(like, p, np.zeros(3))
    u1, _ = dg.pit_values(like, p, np.ones(3))
    n_out = 100.0 * p.r_outer + 2.0
    g = GROSS_ERROR
    prob = like.prob(p)
    # v moves u across the observed outcome's own probability
    np.testing.assert_allclose(u1 - u0, (1 - g) * prob + g / n_out, rtol=1e-12, atol=0)
    for i, k in enumerate(sub.k[:2]):  # detected rows: every outcome 0 .. k - 1 below
        one = rows.take(np.full(int(k) + 1, pick[i]))
        one.k = np.arange(int(k) + 1)  # outcomes 0 .. k (the last is the observed one)
        each = Likelihood(one)
        each.choose_regimes(p)
        pj = each.prob(p)
        assert pj[-1] == pytest.approx(prob[i], rel=1e-12)
        assert u0[i] == pytest.approx((1 - g) * pj[:-1].sum() + g * k / n_out, rel=1e-6, abs=1e-9)
    # the -1 row: every reading lies below it
    assert u0[2] == pytest.approx((1 - g) * (1 - p_cens[2]) + g * (n_out - 1) / n_out, rel=1e-12)
    assert p_cens[2] == pytest.approx(prob[2], rel=1e-12)


def test_normal_scores_are_capped():
    z = dg.normal_scores(np.array([0.0, 0.5, norm.cdf(1.5), 1.0]))
    assert z[0] == -dg.Z_CAP and z[3] == dg.Z_CAP and z[1] == 0.0
    assert z[2] == pytest.approx(1.5, rel=1e-12)


# -- the test's statistics on constructed scores --------------------------------------------


def test_statistics_of_constructed_scores_are_exact():
    """400 independent rows at 20 m (the other bins are empty and merged into one), 100
    with z = +1 and 300 with z = -1: shift = sum z / sqrt(n) = -200 / 20, scatter 0, no
    row in the 1 % tails."""
    z = np.r_[np.full(100, 1.0), np.full(300, -1.0)]
    g = dg.pit_test(norm.cdf(z), np.full(400, 20.0), None, np.zeros(400, bool), np.zeros(400))
    assert [(b.lo, b.hi, b.rows) for b in g.bins] == [(0.0, math.inf, 400)]
    st = g.bins[0].z
    assert st["shift"] == pytest.approx(-10.0, rel=1e-12)
    assert st["scatter"] == pytest.approx(0.0, abs=1e-12)
    assert st["tails"] == pytest.approx(-4.0 / math.sqrt(0.0099 * 400), rel=1e-12)
    assert g.tests == 4 and g.lag_seconds == 0.0
    assert g.p_value == pytest.approx(4 * 2 * norm.sf(10.0), rel=1e-9)
    assert not g.fits and g.worst_feature == "shift"
    assert g.note() == (
        "the model does not describe this walk: readings at every distance are shorter than it predicts (mean PIT "
        f"score -0.50, PIT test p = {g.p_value:.2g}): look for a clock offset between the receiver and the pose logs "
        "(--fit time_offset), a mounting bias of the receiver or its GPS antenna, or a wrong height"
    )


def test_bins_merge_until_each_has_enough_rows():
    r = np.r_[np.full(250, 3.0), np.full(30, 7.0), np.full(300, 12.0), np.full(500, 40.0)]
    z = np.tile([0.5, -0.5], r.shape[0] // 2)
    g = dg.pit_test(norm.cdf(z), r, None, np.zeros(r.shape[0], bool), np.zeros(r.shape[0]))
    # 15-25 (empty) joins its smaller neighbour 25-35 (empty), that joins 10-15, then 5-10 joins 0-5
    assert [(b.lo, b.hi, b.rows) for b in g.bins] == [(0.0, 10.0, 280), (10.0, 35.0, 300), (35.0, math.inf, 500)]
    assert g.tests == 10 and g.fits and g.note() is None


def test_unexpected_censored_rows_use_markov_bound():
    """10 rows say -1 where the model gives it 1e-5 each (400 such rows: 0.004 expected):
    p <= 0.004 / 10, times the 4 statistics."""
    z = np.tile([1.0, -1.0], 200)
    cens = np.zeros(400, bool)
    cens[::40] = True
    g = dg.pit_test(norm.cdf(z), np.full(400, 20.0), None, cens, np.full(400, 1e-5))
    assert g.unexpected_censored == 10
    assert g.expected_unexpected == pytest.approx(4e-3, rel=1e-12)
    assert g.p_unexpected == pytest.approx(1.6e-3, rel=1e-12)  # 4e-4, times 4 statistics
    assert g.p_value == pytest.approx(1.6e-3, rel=1e-12)
    assert not g.fits and g.worst_feature == dg.JUNK
    assert g.note().startswith(
        "the model does not describe this walk: 10 rows say 'nothing heard' (d = -1) where it gives that less than "
        "0.1 % chance (0.004 expected; PIT test p = 0.0016): spurious -1 rows"
    )
    quiet = dg.pit_test(norm.cdf(z), np.full(400, 20.0), None, cens, np.full(400, 0.5))  # -1 is likely there
    assert quiet.unexpected_censored == 0 and quiet.fits


def test_center_statistic_catches_a_scale_mixture():
    """Most rows scatter less than the model allows and some more (what a Gaussian GPS
    error fitted to heavy-tailed error leaves): 300 rows at z = +-0.3, 100 at +-1.8. The
    variance is below 1 (scatter is one-sided) and no row is in the 1 % tails, but 75 % of
    the scores lie in the central half: (300 - 200) / sqrt(0.25 * 400) = 10, tested with
    half of ALPHA."""
    z = np.r_[np.tile([0.3, -0.3], 150), np.tile([1.8, -1.8], 50)]
    args = (norm.cdf(z), np.full(400, 20.0), None, np.zeros(400, bool), np.zeros(400))
    g = dg.pit_test(*args, center=True)
    assert g.center_fraction == 0.75 and g.center_z == pytest.approx(10.0, rel=1e-12)
    assert g.bins[0].z["scatter"] < 0 and g.bins[0].z["shift"] == pytest.approx(0.0, abs=1e-12)
    assert g.tests == 5 and g.worst_feature == "center"
    assert g.p_value == pytest.approx(norm.sf(10.0) / dg.CENTER_WEIGHT, rel=1e-9)
    assert g.note().startswith(
        "the pose-error model does not describe this walk: most readings scatter less than the fitted GPS error "
        "allows and some far more (75 % of the PIT scores in the model's central half, 50 % expected;"
    )
    plain = dg.pit_test(*args)  # without GPS error in the fit: not tested
    assert plain.center_z is None and plain.tests == 4 and plain.fits


def test_time_block_variances_widen_correlated_scores():
    """Scores that share a common error over runs of 60 s (a slow pose error): the
    time-block variance of their sum is several times the independent-rows one, so the
    statistic shrinks by more than 3 (the bandwidth is the floor 4 sqrt(T))."""
    rng = np.random.default_rng(1)
    n = 3600
    slow = np.repeat(rng.standard_normal(n // 60), 60)  # 60 s runs of one common error
    z = (0.8 * slow + 0.6 * rng.standard_normal(n))
    r = np.full(n, 20.0)
    t = np.arange(n, dtype=float)
    indep = dg.pit_test(norm.cdf(z), r, None, np.zeros(n, bool), np.zeros(n))
    blocks = dg.pit_test(norm.cdf(z), r, t, np.zeros(n, bool), np.zeros(n))
    assert abs(blocks.bins[0].z["shift"]) < abs(indep.bins[0].z["shift"]) / 3
    assert blocks.lag_seconds == pytest.approx(4 * math.sqrt(n), rel=1e-12)


# -- on campaigns of the independent generator ----------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_exact_pose_fit_quiet_when_specified_fires_on_spurious_rows(seed):
    table, clean = campaign_table("radial", "exact", (), seed)
    good = fit(table, FitOptions())
    assert good.converged and good.goodness_of_fit.fits
    assert not any(MISFIT_WORDS in n for n in good.notes)
    table, _ = campaign_table("radial", "exact", ("spurious",), seed)
    bad = fit(table, FitOptions(spurious_refit=False))
    gof = bad.goodness_of_fit
    assert bad.converged and not gof.fits and gof.p_value < 1e-10
    injected = int(round(0.02 * clean.heard))  # study_campaigns: 2 % of the heard rows
    assert 0.6 * injected <= gof.unexpected_censored <= injected
    notes = [n for n in bad.notes if MISFIT_WORDS in n]
    assert len(notes) == 1 and f"{gof.unexpected_censored} rows say 'nothing heard'" in notes[0]
    # the default then fits a dropout probability (estimate.dropout_if_spurious), and that fit's check is quiet
    refit = fit(table, FitOptions())
    assert refit.converged and "dropout" in refit.free and refit.goodness_of_fit.fits
    assert refit.notes[0].startswith(f"spurious -1 rows: {gof.unexpected_censored} rows say 'nothing heard'")
    assert not any(MISFIT_WORDS in n for n in refit.notes)


@pytest.mark.slow
def test_pose_error_fit_quiet_when_specified_fires_on_spurious_rows(tmp_path):
    """The default (errors-in-variables) fit, time-block variances: 20-minute level walks
    with Gauss-Markov GPS error, with and without 2 % spurious -1 rows."""
    table, _ = campaign_table("level_rw", "gm", (), 2)
    good = fit(table, FitOptions(free=EIV_FREE))
    assert good.converged and good.goodness_of_fit.fits and good.goodness_of_fit.lag_seconds > 0
    assert not any(MISFIT_WORDS in n for n in good.notes)
    table, _ = campaign_table("level_rw", "gm", ("spurious",), 2)
    bad = fit(table, FitOptions(free=EIV_FREE, spurious_refit=False))
    assert bad.converged and not bad.goodness_of_fit.fits
    assert any("rows say 'nothing heard'" in n for n in bad.notes)
    out = bad.to_json()
    text = json.dumps(out, allow_nan=False)
    gof = json.loads(text)["goodness_of_fit"]
    assert set(gof) == {
        "test", "p_value", "alpha", "fits", "rows", "lag_seconds", "worst", "statistics_tested", "unexpected_censored",
        "unexpected_censored_p_value", "unexpected_censored_expected", "center_fraction", "center_statistic", "bins",
    }  # fmt: skip
    assert gof["fits"] is False and gof["alpha"] == dg.ALPHA and gof["worst"]["statistic"] == dg.JUNK
    assert gof["rows"] == bad.n_used == sum(b["rows"] for b in gof["bins"])
    assert gof["unexpected_censored"] == sum(b["unexpected_censored"] for b in gof["bins"])
    assert gof["bins"][-1]["to_m"] is None and set(gof["bins"][0]["statistics"]) == set(dg.FEATURES)
    line = [x for x in summary(bad).splitlines() if x.startswith("goodness of fit:")]
    assert line == [f"goodness of fit: PIT residuals by distance on {bad.n_used} rows, p = {gof['p_value']:.2g}: "
                    "THE MODEL DOES NOT FIT (see note)"]  # fmt: skip
    assert f"goodness of fit: PIT residuals by distance on {good.n_used} rows" in summary(good)
    md_path, _png, _warning = write_report(tmp_path, table, bad)
    md = md_path.read_text()
    section = md[md.index("## Goodness of fit"):]
    assert f"on {bad.n_used} rows, variances from time blocks of {gof['lag_seconds']:.0f} s" in section
    assert f"p = {gof['p_value']:.2g} ({gof['statistics_tested']} statistics" in section
    assert "**the model does not fit** (see the notes)" in section
    first = gof["bins"][0]
    assert f"| {first['from_m']:g} - {first['to_m']:g} | {first['rows']} | {first['mean_z']:+.3f} |" in section


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(200, 900),
    seed=st.integers(0, 2**32 - 1),
    far=st.floats(1.0, 80.0),
    with_t=st.booleans(),
    center=st.booleans(),
)
def test_pit_test_is_finite_bounded_and_order_free(n, seed, far, with_t, center):
    """Any scores, distances, -1 flags and probabilities: p in [0, 1], the verdict is
    p >= ALPHA, every row in one bin, the JSON finite; with independent rows the result
    does not depend on the rows' order."""
    rng = np.random.default_rng(seed)
    u = rng.random(n) ** rng.uniform(0.3, 3.0)  # from uniform to strongly skewed
    u[rng.random(n) < 0.01] = rng.choice([0.0, 1.0])  # the clipped ends too
    r = rng.uniform(0.5, far, n)
    cens = rng.random(n) < 0.2
    pc = rng.random(n) ** 6
    t = np.sort(rng.uniform(0, 2 * n, n)) if with_t else None
    g = dg.pit_test(u, r, t, cens, pc, center=center)
    assert 0.0 <= g.p_value <= 1.0 and g.fits == (g.p_value >= dg.ALPHA)
    assert sum(b.rows for b in g.bins) == n and all(b.rows >= dg.MIN_BIN_ROWS for b in g.bins)
    json.dumps(g.to_json(), allow_nan=False)
    assert (g.note() is None) == g.fits
    if t is None:
        perm = rng.permutation(n)
        h = dg.pit_test(u[perm], r[perm], None, cens[perm], pc[perm], center=center)
        assert h.p_value == pytest.approx(g.p_value, rel=1e-9, abs=1e-300)
        assert h.worst_feature == g.worst_feature and h.unexpected_censored == g.unexpected_censored
