"""The fit's faster numerics against the slow, direct forms they replace.

* the near-kink rule of ``smoothed_ball_disk_cdf`` against adaptive quadrature, for the
  pose-error spreads of the errors-in-variables model (s3 up to 0.45);
* ``smoothed_ball_disk_bin`` (one series evaluation per narrow bin) against the
  difference of two CDFs computed with a fine rule;
* the Newey-West meat from window sums against the lag-by-lag sum;
* an evaluation in blocks (on one or two threads) gives the same per-row log P, bit for bit.
* the forward-difference gradient of the full-data steps against the exact one, and
  their search against the central one's.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate
from scipy.stats import norm

import bench.fit.special as special
from bench.fit.covariance import time_block_meat
from bench.fit.eiv import usable
from bench.fit.estimate import check_table
from bench.fit.result import FitOptions
from bench.fit.likelihood import Likelihood, Params
from bench.fit.special import ball_disk_cdf, smoothed_ball_disk_bin, smoothed_ball_disk_cdf
from bench.fit.search import Differences, fd_gradient, forward_gradient, newton
from bench.fit.stages import FULL_FINISH_TOL, FULL_TOL
from emulator.receiver.model import ModelParams
from fit_campaign import emulate_campaign


def quad_smoothed(lt, gamma, s3):
    kinks = sorted(((math.log(abs(gamma - 1)) - lt) / s3, (math.log(gamma + 1) - lt) / s3))
    inside = [z for z in kinks if -12 < z < 12]
    return integrate.quad(
        lambda z: norm.pdf(z) * ball_disk_cdf(np.array([math.exp(lt + s3 * z)]), np.array([gamma]), 24)[0],
        -12, 12, points=inside or None, limit=400, epsabs=1e-13,
    )[0]  # fmt: skip


@pytest.mark.parametrize(
    ("gamma", "s3", "z_from_top"),
    [(30.0, 0.1, 0.5), (30.0, 0.1, -3.0), (3.0, 0.3, 1.0), (0.5, 0.2, -0.5), (0.5, 0.45, 2.0), (1.5, 0.05, -6.5), (8.0, 0.02, 7.0)],
)
def test_near_kink_rule_with_large_pose_error(gamma, s3, z_from_top):
    """Rows a few s.d. from the upper kink (z_from_top s.d. below log(gamma + 1))."""
    lt = math.log(gamma + 1) - z_from_top * s3
    got = smoothed_ball_disk_cdf(np.array([lt]), np.array([gamma]), np.array([s3]))[0]
    assert abs(got - quad_smoothed(lt, gamma, s3)) < 3e-6


def test_bin_series_is_the_difference_of_two_cdfs():
    rng = np.random.default_rng(7)
    n = 3000
    gamma = np.exp(rng.uniform(-1.0, 4.0, n))
    s3 = rng.uniform(0.03, 0.4, n)
    mid = np.log(gamma + 1) + s3 * rng.uniform(-6.0, 4.0, n)
    w = rng.uniform(1e-3, special.BIN_W_MAX, n)
    got = smoothed_ball_disk_bin(mid, w * s3, gamma, s3)
    assert np.all(np.isfinite(got)) and np.all(got >= 0)
    old = special.PIECE, special._XP, special._WP
    try:  # the reference: a fine rule (12 nodes per 0.25 s.d.) and the plain difference
        special.PIECE = 0.25
        special._XP, special._WP = np.polynomial.legendre.leggauss(12)
        ref = smoothed_ball_disk_cdf(mid + 0.5 * w * s3, gamma, s3) - smoothed_ball_disk_cdf(mid - 0.5 * w * s3, gamma, s3)
    finally:
        special.PIECE, special._XP, special._WP = old
    big = ref > 1e-6  # below that the reference's own cancellation dominates
    assert big.sum() > n // 2
    assert np.max(np.abs(np.log(got[big] / ref[big]))) < 2e-3
    assert np.median(np.abs(np.log(got[big] / ref[big]))) < 1e-6


def lag_by_lag_meat(scores, t, lag):
    sec = np.floor(t - t.min()).astype(np.int64)
    T = int(sec.max()) + 1
    x = np.stack([np.bincount(sec, weights=scores[:, j], minlength=T) for j in range(scores.shape[1])], axis=1)
    x -= x.mean(axis=0)
    big_l = int(math.floor(lag))
    meat = x.T @ x
    for l in range(1, big_l + 1):
        g = x[l:].T @ x[:-l]
        meat += (1.0 - l / (big_l + 1.0)) * (g + g.T)
    return meat


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 400), st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_window_sum_meat_is_the_lag_by_lag_sum(n, p, seed):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, n, n))
    scores = np.cumsum(rng.standard_normal((n, p)), axis=0) * 0.1 + rng.standard_normal((n, p))
    meat, lag = time_block_meat(scores, t)
    ref = lag_by_lag_meat(scores, t, lag)
    assert np.allclose(meat, ref, rtol=1e-10, atol=1e-10 * np.max(np.abs(ref)))


@pytest.mark.parametrize("threads", [1, 2])
def test_evaluation_in_blocks_is_bit_for_bit_the_same(threads):
    table = emulate_campaign(0, ModelParams(kappa_eq=1.542, r_en=80.0), seed=3, n_rows=4 * 1000 + 11)
    rows = usable(check_table(table, FitOptions()))
    p = Params(kappa_eq=1.55, r_en=75.0, pose_sigma=2e-3)
    one = Likelihood(rows)
    one.choose_regimes(p)
    blocks = Likelihood(rows)
    blocks.choose_regimes(p)
    blocks.block, blocks.threads = 1000, threads
    assert blocks._split()
    a, b = one.logp(p), blocks.logp(p)
    assert a.shape == b.shape and np.array_equal(a, b)
    assert len(blocks._blocks[2]) == 5


# -- forward-difference steps of the full-data search (search.forward_gradient) ---------------

A_QUAD = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.2], [0.5, -0.2, 2.0]])
B_QUAD = np.array([0.3, -1.0, 2.0])


def quadratic(th):
    return 0.5 * th @ A_QUAD @ th + B_QUAD @ th


def test_forward_gradient_takes_off_the_curvature_term():
    """On a quadratic the forward difference is the gradient plus h f''/2 exactly: with the
    true curvature it is the gradient, with none it is off by that term."""
    th, h = np.array([0.1, -0.2, 0.3]), np.array([1e-2, 2e-2, 5e-3])
    g = A_QUAD @ th + B_QUAD
    got = forward_gradient(quadratic, th, h, quadratic(th), np.diag(A_QUAD))
    assert np.max(np.abs(got - g)) < 1e-9
    plain = forward_gradient(quadratic, th, h, quadratic(th), np.zeros(3))
    assert np.max(np.abs(plain - g - 0.5 * np.diag(A_QUAD) * h)) < 1e-9
    # a negative curvature is no correction (floored at 0)
    assert np.array_equal(forward_gradient(quadratic, th, h, quadratic(th), -np.ones(3)), plain)


def test_forward_gradient_points_are_the_central_stencils_first():
    """Its points are the first p of fd_gradient's, the same floats, so a memoising
    likelihood answers them again when the central stencil follows at the same point."""
    th, h = np.array([0.1, -0.2, 0.3]), np.array([1e-2, 2e-2, 5e-3])
    seen: list = []

    def recorded(x):
        seen.append(tuple(x))
        return quadratic(x)

    forward_gradient(recorded, th, h, quadratic(th), np.diag(A_QUAD))
    forward = set(seen)
    seen.clear()
    fd_gradient(recorded, th, h, quadratic(th), hessian=True)
    assert len(forward) == 3 and forward <= set(seen)


# A smooth, not quite quadratic objective in the four parameters of the default
# errors-in-variables fit, with curvatures of a 1e5-row fit (standard errors 0.003-0.3).
FREE4 = ("kappa_eq", "r_en", "gps_sigma", "attitude_sigma")
SE4 = np.array([0.0026, 0.0044, 0.015, 0.25])
CORR4 = np.array([[1.0, 0.3, -0.2, 0.4], [0.3, 1.0, 0.5, -0.1], [-0.2, 0.5, 1.0, 0.2], [0.4, -0.1, 0.2, 1.0]])
HESS4 = np.linalg.inv(CORR4 * np.outer(SE4, SE4))
CENTRE4 = np.log([1.5, 80.0, 1.0, 0.05])


def objective4(th):
    u = (th - CENTRE4) / SE4
    return 0.5 * (th - CENTRE4) @ HESS4 @ (th - CENTRE4) + 0.05 * float(np.sum(u**3)) + 0.01 * float(np.sum(u**4))


def optimum4():
    th = CENTRE4.copy()
    for _ in range(50):  # Newton on the analytic gradient and Hessian
        u = (th - CENTRE4) / SE4
        g = HESS4 @ (th - CENTRE4) + (0.15 * u**2 + 0.04 * u**3) / SE4
        h = HESS4 + np.diag((0.3 * u + 0.12 * u**2) / SE4**2)
        th = th - np.linalg.solve(h, g)
    return th, h


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_steps_reach_the_central_searchs_optimum_with_fewer_points(seed):
    """The full-data stage's search (BFGS from a noisy start Hessian, finish below
    FULL_FINISH_TOL) with forward-difference steps ends within 0.01 standard errors of the
    optimum, as the central one does, with fewer evaluations, and its Hessian (for the
    standard errors) is the one at the optimum to within 3 %."""
    rng = np.random.default_rng(seed)
    opt, h_opt = optimum4()
    start = opt + SE4 * rng.uniform(-4.0, 4.0, 4)
    noise = np.exp(rng.uniform(-0.25, 0.25, 4))
    hess0 = HESS4 * np.outer(noise, noise)
    steps = 0.3 * SE4
    ends = {}
    for forward in (False, True):
        count = [0]

        def f(th):
            count[0] += 1
            return objective4(th)

        res = newton(
            Differences(f, forward=forward), start, FREE4, 10, FULL_TOL, h=steps, held=np.zeros(4, bool), hess0=hess0,
            finish=FULL_FINISH_TOL,
        )
        assert res.ok
        assert np.max(np.abs(res.theta - opt) / SE4) < 0.01
        se_got = np.sqrt(np.diag(np.linalg.inv(res.hess)))
        assert np.max(np.abs(se_got / np.sqrt(np.diag(np.linalg.inv(h_opt))) - 1)) < 0.03
        ends[forward] = count[0]
    assert ends[True] < ends[False]
