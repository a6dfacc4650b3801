"""The fit's probability model against the emulator it describes.

* the closed-form pieces against numerical integration;
* P(d = k) summed over every outcome is 1;
* P(d = k) against the emulator's own frequencies (emulator.receiver.model.measure + the noise
  effect) for fixed geometries;
* likelihood.simulate is the emulator, integer for integer, for the same noise points.
"""

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import norm

from bench.fit.likelihood import Likelihood, Params, Rows, geometry, simulate
from bench.fit.special import ball_disk_cdf, epan_gauss_cdf, epan_gauss_interval, smoothed_ball_disk_cdf
from emulator.receiver.noise import NoiseEffect
from emulator.receiver.model import ModelParams, measure
from emulator.frames.rotation import rotation_components, unit_quaternion_components


def quad_epan_gauss(u, e, s):
    return integrate.quad(lambda x: 0.75 * (1 - x * x) * norm.cdf((u - e * x) / s), -1, 1, epsabs=1e-14, epsrel=1e-13)[0]


@pytest.mark.parametrize(
    ("u", "e", "s"),
    [(0.0, 1e-3, 1e-3), (2e-3, 1e-3, 1e-4), (-9e-4, 1e-3, 1e-5), (5e-4, 1e-6, 1e-3), (3e-3, 0.01, 0.002), (-0.05, 0.02, 0.01)],
)
def test_epan_gauss_cdf_matches_quadrature(u, e, s):
    assert abs(epan_gauss_cdf(np.array([u]), np.array([e]), s)[0] - quad_epan_gauss(u, e, s)) < 1e-11


def test_epan_gauss_limits_and_symmetry():
    u = np.array([-np.inf, np.inf, 0.0])
    assert epan_gauss_cdf(u, np.full(3, 0.01), 0.001).tolist() == [0.0, 1.0, 0.5]
    assert epan_gauss_cdf(np.array([0.005]), np.array([0.01]), 0.0)[0] == pytest.approx((2 + 1.5 - 0.125) / 4)
    a, b = np.array([0.001, -0.003]), np.array([0.004, -0.001])
    assert np.allclose(epan_gauss_interval(a, b, np.full(2, 0.002), 5e-4), epan_gauss_interval(-b, -a, np.full(2, 0.002), 5e-4))


def test_ball_disk_cdf_closed_forms_and_monte_carlo():
    # gamma = 0: P(|n| <= t) = 1 - (1 - t^2)^(3/2) for the projection of the unit ball.
    t = np.linspace(0.0, 1.0, 11)
    assert np.allclose(ball_disk_cdf(t, np.zeros_like(t)), 1 - (1 - t * t) ** 1.5, atol=1e-12)
    assert ball_disk_cdf(np.array([4.0, 2.0]), np.array([3.0, 3.0])).tolist() == [1.0, 0.0]  # outside gamma +- 1
    rng = np.random.default_rng(0)
    z = rng.standard_normal((400_000, 5))
    u = z[:, :3] / np.linalg.norm(z, axis=1, keepdims=True)
    for gamma in (0.3, 1.0, 2.5):
        m = np.hypot(gamma + u[:, 0], u[:, 1])
        ts = np.linspace(max(0.0, gamma - 1.0), gamma + 1.0, 9)
        mc = np.array([(m <= v).mean() for v in ts])
        assert np.max(np.abs(ball_disk_cdf(ts, np.full_like(ts, gamma)) - mc)) < 4 * math.sqrt(0.25 / m.size)


def test_smoothed_cdf_is_the_gaussian_average():
    for gamma, s3, lt in ((2.77, 0.0037, 1.3051), (30.7, 0.009, 3.447), (0.5, 0.0015, -0.6965), (80.0, 0.001, 4.3774)):
        ref = integrate.quad(
            lambda z: norm.pdf(z) * ball_disk_cdf(np.array([math.exp(lt + s3 * z)]), np.array([gamma]), 24)[0],
            -12, 12, points=sorted(((math.log(abs(gamma - 1)) - lt) / s3, (math.log(gamma + 1) - lt) / s3)), limit=400,
        )[0]  # fmt: skip
        assert abs(smoothed_ball_disk_cdf(np.array([lt]), np.array([gamma]), s3)[0] - ref) < 3e-6


def one_geometry(r, seed, n=1):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    q = rng.normal(size=4)
    return (
        np.tile(direction * r, (n, 1)), np.tile(q / np.linalg.norm(q), (n, 1)),
        np.zeros((1, 3)), np.array([[0.9, 0.1, -0.3, 0.2]]),
    )  # fmt: skip


@pytest.mark.parametrize("r", [2.8, 9.0, 33.0, 48.0, 70.0])
def test_probabilities_of_all_outcomes_sum_to_one(r):
    rx, rq, tx, tq = one_geometry(r, 4)
    k = np.arange(-1, 5001)
    geo = geometry(np.repeat(rx, k.size, 0), np.repeat(rq, k.size, 0), np.repeat(tx, k.size, 0), np.repeat(tq, k.size, 0))
    for sigma in (1e-4, 0.01):
        like = Likelihood(Rows(k, geo))
        p = Params(r_en=60.0, pose_sigma=sigma)
        like.choose_regimes(p)
        assert like.prob(p).sum() == pytest.approx(1.0, abs=2e-6)


@pytest.mark.parametrize("r", [2.9, 8.0, 25.0, 42.0, 55.0])
def test_model_matches_emulator_frequencies(r):
    n = 40_000
    rx, rq, tx, tq = one_geometry(r, int(r * 10), n)
    params = ModelParams(r_en=60.0)
    d = measure(rx, rq, tx, tq, params, noise=NoiseEffect(int(r)).draw(n, 1)).d[:, 0]
    values, counts = np.unique(d, return_counts=True)
    m = values.size
    geo = geometry(rx[:m], rq[:m], np.repeat(tx, m, 0), np.repeat(tq, m, 0))
    like = Likelihood(Rows(values.astype(np.int64), geo))
    p = Params(r_en=60.0, pose_sigma=1e-7)  # the emulator has exact poses
    like.choose_regimes(p)
    model = like.prob(p)
    order = np.argsort(np.where(values == -1, 10**9, values))  # -1 last: "beyond"
    ks = np.max(np.abs(np.cumsum(counts[order]) / n - np.cumsum(model[order])))
    assert ks < 1.63 / math.sqrt(n)  # Kolmogorov 1 % critical value
    assert model.sum() > 0.995


def test_simulate_is_the_emulator_for_the_same_noise_points():
    from fit_campaign import emulate_campaign

    tab = emulate_campaign(10, ModelParams(r_en=50.0), seed=1)
    geo = geometry(tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat)
    k = simulate(geo, Params(r_en=50.0, pose_sigma=0.0), np.random.default_rng(5))
    z = np.random.default_rng(5).standard_normal((len(tab), 5))
    u = z[:, :3] / np.sqrt((z * z).sum(1))[:, None]  # receiver-frame points of the unit ball
    world = np.einsum("ijn,nj->ni", rotation_components(unit_quaternion_components(tab.rx_quat)), u)
    d = measure(tab.rx_pos, tab.rx_quat, tab.tx_pos[:1], tab.tx_quat[:1], ModelParams(r_en=50.0), noise=world[:, None]).d[:, 0]
    assert np.array_equal(k, d)
    assert 0 < np.sum(k == -1) < len(k)
