"""The fit's faster numerics against the slow, direct forms they replace.

* the near-kink rule of ``smoothed_ball_disk_cdf`` against adaptive quadrature, for the
  pose-error spreads of the errors-in-variables model (s3 up to 0.45);
* ``smoothed_ball_disk_bin`` (one series evaluation per narrow bin) against the
  difference of two CDFs computed with a fine rule;
* the Newey-West meat from window sums against the lag-by-lag sum;
* an evaluation in blocks (on one or two threads) gives the same per-row log P, bit for bit.
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
