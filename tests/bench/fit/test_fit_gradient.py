"""The fit's analytic derivatives (issue 20) against central differences, and the
gradient route's fit against the finite-difference route it replaces for exact poses.

Tolerances, and why:

* ``epan_gauss_density``: the central differences' own error. With steps of 1e-3 (f) and
  2e-2 (f') of min(e, s) their truncation error is ~1e-7 of f's scale 1/max(e, s) and
  ~1e-5 of f''s scale 1/(min max) (measured over 2e5 random triples: 3.7e-7, 1.3e-5).
* ``ball_disk_cdf(grad=True)``: exact derivatives of G by the same 8-node rule as G, so
  they differ from the derivative of the 8-node value by the rule's error. Against
  differences of a 96-node G, away from the configurations where the rule's integrand
  has a feature narrower than the band (|t - gamma| or |t + gamma - 1| below 0.05), the
  largest error over 5e4 random pairs was 8e-5 (1 + |derivative|): the bound is 2e-4.
  (At t = gamma it reaches 4e-4 of the derivative, and the value rule errs there alike;
  the likelihood-level check below is the one that bounds what the fit sees.)
* ``Likelihood.logp_grad``: what matters for the fit is the summed gradient. An error
  of e times its sampling s.d. sqrt(sum s_i^2) moves the estimate by about e standard
  errors; the brief allows 0.02. The reference is central differences of the likelihood
  computed with a finer rule (pieces of 0.5 s.d. near the kinks, 24 nodes): differences
  of the default rule carry its own node-layout error near the kinks (a row 4 s.d. past
  the top kink: d C / d log t = 8.16808e-7 analytic, 8.16810e-7 by adaptive quadrature,
  7.39e-7 by differences of the default rule) and were up to 0.027 s.d. off; against the
  finer rule the largest error over 31 draws was 0.0092 (pose_sigma), 0.0054 (kappa_eq),
  0.0046 (r_en).
* The fit: estimates within 0.02 s.e. of the finite-difference route, standard errors
  within 2 % (the likelihood's curvature in r_en wavers by ~1 % over 0.02 s.e., so two
  Hessians by differences at points that close differ by that much).
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bench.fit.stages as stages_module
import bench.fit.special as special
from bench.fit.eiv import usable
from bench.fit.estimate import fit_table
from bench.fit.result import FitOptions
from bench.fit.rows import rows_from_table
from bench.fit.likelihood import Likelihood, Params, from_params, to_params
from bench.fit.special import ball_disk_cdf, epan_gauss_cdf, epan_gauss_density, smoothed_ball_disk_cdf
from emulator.receiver.model import ModelParams
from fit_campaign import Walk, emulate_campaign

NAMES = ("kappa_eq", "r_en", "pose_sigma")


@settings(max_examples=200, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-9.0, -2.0), st.floats(-9.0, -2.0))
def test_epan_gauss_density_matches_differences(z, log_e, log_s):
    e, s = math.exp(log_e), math.exp(log_s)
    big, small = max(e, s), min(e, s)
    u = np.array([2.0 * z * big])
    f, df = epan_gauss_density(u, np.array([e]), s)
    cdf = lambda x: epan_gauss_cdf(np.array([x]), np.array([e]), s)[0]  # noqa: E731
    h1, h2 = 1e-3 * small, 2e-2 * small
    assert abs(f[0] - (cdf(u[0] + h1) - cdf(u[0] - h1)) / (2 * h1)) <= 1e-6 / big
    assert abs(df[0] - (cdf(u[0] + h2) - 2 * cdf(u[0]) + cdf(u[0] - h2)) / h2**2) <= 5e-5 / (small * big)
    # the derivatives in e and s the likelihood takes from f and f'
    de, ds = 1e-5 * e, 1e-5 * s
    d_e = (epan_gauss_cdf(u, np.array([e + de]), s)[0] - epan_gauss_cdf(u, np.array([e - de]), s)[0]) / (2 * de)
    d_s = (epan_gauss_cdf(u, np.array([e]), s + ds)[0] - epan_gauss_cdf(u, np.array([e]), s - ds)[0]) / (2 * ds)
    assert abs(e * d_e + (u[0] * f[0] + s * s * df[0])) <= 1e-5
    assert abs(s * d_s - s * s * df[0]) <= 1e-5


def test_epan_gauss_density_at_infinity_and_series_side():
    f, df = epan_gauss_density(np.array([-np.inf, np.inf]), np.array([0.01, 0.01]), 0.001)
    assert f.tolist() == [0.0, 0.0] and df.tolist() == [0.0, 0.0]
    # e/s below SERIES_BELOW: the series' derivative; at u = 0 f = phi(0)/s (1 - h^2/10 + h^4/280 * 3)
    s, e = 0.01, 0.0004
    h2 = (e / s) ** 2
    f, df = epan_gauss_density(np.array([0.0]), np.array([e]), s)
    assert f[0] == pytest.approx((1 - 0.1 * h2 + 3 * h2 * h2 / 280) / (math.sqrt(2 * math.pi) * s), rel=1e-14)
    assert df[0] == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(0.05, 10.0), st.floats(0.05, 10.0))
def test_ball_disk_cdf_derivatives_match_a_fine_rule(t, gamma):
    # only where G has a band to integrate, and away from its narrow features (docstring),
    # including the band's closing edge |t - gamma| -> 1, where the reference's difference
    # step straddles G's kink (hypothesis found t = 9, gamma = 10 - 2e-15: band 2e-15 wide)
    if not (0.05 <= abs(t - gamma) <= 0.95 and abs(t + gamma - 1.0) >= 0.05):
        return
    g0, d_t, d_g = ball_disk_cdf(np.array([t]), np.array([gamma]), grad=True)
    assert g0[0] == ball_disk_cdf(np.array([t]), np.array([gamma]))[0]
    h = 1e-5
    fine = lambda tt, gg: ball_disk_cdf(np.array([tt]), np.array([gg]), 96)[0]  # noqa: E731
    ref_t = (fine(t * math.exp(h), gamma) - fine(t * math.exp(-h), gamma)) / (2 * h)
    ref_g = (fine(t, gamma * math.exp(h)) - fine(t, gamma * math.exp(-h))) / (2 * h)
    assert abs(d_t[0] - ref_t) <= 2e-4 * (1 + abs(ref_t))
    assert abs(d_g[0] - ref_g) <= 2e-4 * (1 + abs(ref_g))


def test_ball_disk_cdf_derivative_closed_forms():
    # gamma -> 0: G = 1 - (1 - t^2)^(3/2), t dG/dt = 3 t^2 sqrt(1 - t^2); no band: zero
    t = np.array([0.2, 0.5, 0.9])
    _g, d_t, d_g = ball_disk_cdf(t, np.full(3, 1e-9), grad=True)
    assert np.allclose(d_t, 3 * t * t * np.sqrt(1 - t * t), rtol=1e-7, atol=0)
    assert np.all(np.abs(d_g) < 1e-7)
    _g, d_t, d_g = ball_disk_cdf(np.array([4.0, 2.0]), np.array([3.0, 3.0]), grad=True)
    assert d_t.tolist() == [0.0, 0.0] and d_g.tolist() == [0.0, 0.0]


@settings(max_examples=100, deadline=None)
@given(st.floats(0.1, 8.0), st.floats(-4.0, 4.0), st.floats(math.log(3e-4), math.log(0.03)))
def test_smoothed_derivatives_far_from_the_kinks(gamma, offset, log_s3):
    # the Gauss-Hermite rules (rows farther than Z_KINK + Z_BLEND s.d. from both kinks)
    s3 = math.exp(log_s3)
    lt = math.log(gamma) + offset * 0.2
    z1 = (math.log(abs(gamma - 1.0)) - lt) / s3 if gamma != 1.0 else 0.0
    z2 = (math.log(gamma + 1.0) - lt) / s3
    if min(abs(z1), abs(z2)) < 9.0 or abs(gamma - 1.0) < 0.05 or abs(math.exp(lt) - gamma) < 0.05:
        return  # near t = gamma the rule's integrand has a feature of width |t - gamma| (docstring)
    c, d_lt, d_lg, d_s3 = smoothed_ball_disk_cdf(np.array([lt]), np.array([gamma]), s3, grad=True)
    assert c[0] == smoothed_ball_disk_cdf(np.array([lt]), np.array([gamma]), s3)[0]
    f = lambda a, b, c_: smoothed_ball_disk_cdf(np.array([a]), np.array([b]), c_)[0]  # noqa: E731
    h = 1e-5
    ref = (
        (f(lt + h, gamma, s3) - f(lt - h, gamma, s3)) / (2 * h),
        (f(lt, gamma * math.exp(h), s3) - f(lt, gamma * math.exp(-h), s3)) / (2 * h),
        (f(lt, gamma, s3 + h * s3) - f(lt, gamma, s3 - h * s3)) / (2 * h * s3),
    )
    # the 8-node rule's error (~1e-7 in G) against the exact derivative, plus the differences'
    for got, want, scale in zip((d_lt[0], d_lg[0], d_s3[0]), ref, (1.0, 1.0, 1.0 / s3)):
        assert abs(got - want) <= 2e-4 * (1 + abs(want)) + 1e-9 * scale


def test_smoothed_derivatives_near_the_kinks():
    # the piecewise rule and the blend (its weight's own derivative included)
    rng = np.random.default_rng(2)
    n = 4000
    gamma = np.exp(rng.uniform(-2, 2, n))
    kink = np.where(rng.random(n) < 0.5, np.log(np.abs(gamma - 1)), np.log(gamma + 1))
    s3 = np.exp(rng.uniform(np.log(3e-4), np.log(0.3), n))
    lt = kink + s3 * rng.uniform(-9, 9, n)
    _c, d_lt, d_lg, d_s3 = smoothed_ball_disk_cdf(lt, gamma, s3, grad=True)
    h = 1e-3 * s3
    f = lambda a, b, c_: smoothed_ball_disk_cdf(a, b, c_)  # noqa: E731
    for got, want in (
        (d_lt, (f(lt + h, gamma, s3) - f(lt - h, gamma, s3)) / (2 * h)),
        (d_lg, (f(lt, gamma * np.exp(h), s3) - f(lt, gamma * np.exp(-h), s3)) / (2 * h)),
        (d_s3 * s3, (f(lt, gamma, s3 + h) - f(lt, gamma, s3 - h)) / (2 * h) * s3),
    ):
        err = np.abs(got - want)
        # typical rows agree to the rule's accuracy; the few within a band of the kinks
        # whose integrand the 8-node rule resolves poorly differ by up to ~3e-3
        assert np.median(err) < 1e-7
        assert np.quantile(err, 0.99) < 1e-3
        assert err.max() < 1e-2


@pytest.fixture(scope="module")
def campaigns():
    return [usable(rows_from_table(emulate_campaign(20, ModelParams(), seed=seed))) for seed in range(3)]


@pytest.mark.slow
@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2), st.floats(-0.01, 0.01), st.floats(-0.3, 0.3), st.floats(math.log(1e-4), math.log(0.02)))
def test_logp_grad_matches_differences_of_the_likelihood(campaigns, which, dk, dr, log_sigma):
    rows = campaigns[which]
    p = Params(kappa_eq=1.542 * math.exp(dk), r_en=80.0 * math.exp(dr), pose_sigma=math.exp(log_sigma))
    like = Likelihood(rows)
    like.choose_regimes(p)
    logp, d = like.logp_grad(p)
    assert np.array_equal(logp, like.logp(p))  # the same values, bit for bit
    assert like.n_evals == 2
    theta = from_params(p, NAMES)
    saved = special.PIECE, special.G_NODES
    special.PIECE, special.G_NODES = 0.5, 24  # the finer rule (module docstring)
    try:
        for j, h in enumerate((1e-6, 1e-5, 1e-4)):
            e = np.zeros(3)
            e[j] = h
            up, down = like.logp(to_params(p, NAMES, theta + e)), like.logp(to_params(p, NAMES, theta - e))
            fd = (up.sum() - down.sum()) / (2 * h)
            assert abs(d[j].sum() - fd) <= 0.02 * math.sqrt(float(np.sum(d[j] ** 2))), NAMES[j]
    finally:
        special.PIECE, special.G_NODES = saved


def test_logp_grad_is_for_exact_poses_only(campaigns):
    like = Likelihood(campaigns[0])
    assert not like.has_grad(Params(pose_sigma=0.0))
    with pytest.raises(ValueError, match="analytic derivatives need exact poses"):
        like.logp_grad(Params(pose_sigma=0.0))


def noisy_poses():
    """A campaign whose distances carry a 0.3 % relative pose error: pose_sigma is fitted
    inside its range (three live parameters)."""
    from bench.fit.likelihood import geometry, simulate
    from bench.fit.table import Table

    tab = emulate_campaign(20, ModelParams(), seed=4)
    geo = geometry(tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat)
    d = simulate(geo, Params(pose_sigma=0.003), np.random.default_rng(4))
    return Table.from_columns("noisy", tab.t, tab.seq, tab.id, d, tab.delta, tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat)


@pytest.mark.parametrize(
    "table",
    [
        pytest.param(lambda: emulate_campaign(20, ModelParams(), seed=0), id="20min"),
        pytest.param(lambda: emulate_campaign(20, ModelParams(), seed=2, walk=Walk(r_min=30.0, r_max=65.0)), id="30-65m"),
        pytest.param(noisy_poses, id="pose_sigma-inside"),
    ],
)
def test_gradient_route_fit_is_the_difference_route_fit(table, monkeypatch):
    tab = table()
    new = fit_table(tab)
    with monkeypatch.context() as m:
        m.setattr(stages_module, "analytic", lambda *a: False)
        old = fit_table(tab)
    assert new.converged and old.converged
    live = [n for n in NAMES if old.se[n] == old.se[n]]  # pose_sigma at its floor has no s.e.
    assert "kappa_eq" in live and "r_en" in live
    for name in live:
        assert abs(new.estimate[name] - old.estimate[name]) <= 0.02 * old.se[name], name
        assert new.se[name] == pytest.approx(old.se[name], rel=0.02), name
    if "pose_sigma" not in live:  # exact poses: both at its floor
        assert new.estimate["pose_sigma"] == old.estimate["pose_sigma"] == 1e-4
    assert new.n_evals < old.n_evals / 2


def test_all_rows_stage_ends_with_one_unevaluated_newton_step(monkeypatch):
    """Above SUBSAMPLE rows the all-rows search stops at a decrement of FINISH_TOL, takes the
    Hessian there and ends with one Newton step with it, not evaluated: the same estimates
    (0.02 s.e.), standard errors (1 %) and log-likelihood (1e-3 nats) as a search to
    FULL_TOL with the Hessian at its end, with one pass over all rows fewer here."""
    tab = emulate_campaign(0, ModelParams(kappa_eq=1.542, r_en=80.0), seed=400, n_rows=12000)
    new = fit_table(tab)
    with monkeypatch.context() as m:
        m.setattr(stages_module, "FINISH_TOL", None)
        old = fit_table(tab)
    assert new.converged and old.converged
    for name in ("kappa_eq", "r_en"):
        assert abs(new.estimate[name] - old.estimate[name]) <= 0.02 * old.se[name], name
        assert new.se[name] == pytest.approx(old.se[name], rel=0.01), name
    assert abs(new.log_likelihood - old.log_likelihood) < 1e-3
    assert new.n_evals_all_rows == old.n_evals_all_rows - 1
