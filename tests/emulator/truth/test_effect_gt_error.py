"""The ``ground_truth_error`` effect: GPS noise/bias/dropouts, attitude noise.

Statistical checks use 5-sigma bounds from the sampling distributions (mean: sigma/sqrt(n);
sample variance of a Gaussian: sigma^2 sqrt(2/(n-1)); dropouts: binomial).
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from emulator.truth.error import GroundTruthError, GroundTruthErrorConfig
from firmware_proto.errors import InputError, PoseError

N = 200_000


def positions(n, seed=0):
    return np.random.default_rng(seed).uniform(-500, 500, (n, 3))


def unit_quats(n, seed=0):
    return Rotation.random(n, rng=np.random.default_rng(seed)).as_quat(scalar_first=True)


def rng_state(gte):
    return gte._rng_gps.bit_generator.state, gte._rng_att.bit_generator.state


def test_zero_config_is_identity_and_draws_nothing():
    gte = GroundTruthError(GroundTruthErrorConfig(), seed=1)
    before = rng_state(gte)
    p, q = positions(100), unit_quats(100)
    out, valid = gte.gps(p)
    assert np.array_equal(out, p) and valid.all()
    assert np.array_equal(gte.attitude(q), q)
    assert rng_state(gte) == before


def test_bias_alone_is_exact_and_draws_nothing():
    gte = GroundTruthError(GroundTruthErrorConfig(gps_bias_m=(1.5, -2.0, 0.25)), seed=1)
    before = rng_state(gte)
    p = positions(1000)
    out, valid = gte.gps(p)
    assert np.array_equal(out, p + [1.5, -2.0, 0.25]) and valid.all()
    assert rng_state(gte) == before


def test_gps_noise_mean_and_sigma_per_axis():
    sigma, bias = np.array([1.0, 2.5, 0.0]), np.array([3.0, -1.0, 0.5])
    gte = GroundTruthError(GroundTruthErrorConfig(gps_sigma_m=tuple(sigma), gps_bias_m=tuple(bias)), seed=3)
    p = positions(N)
    out, valid = gte.gps(p)
    assert valid.all() and np.all(np.isfinite(out))
    err = out - p
    for axis in (0, 1):
        s = sigma[axis]
        assert abs(err[:, axis].mean() - bias[axis]) < 5 * s / math.sqrt(N)
        assert abs(err[:, axis].var(ddof=1) - s * s) < 5 * s * s * math.sqrt(2 / (N - 1))
    # A zero-sigma axis carries the bias exactly (up to the rounding of p + bias - p).
    assert np.allclose(err[:, 2], 0.5, rtol=0, atol=1e-12)
    # Axes are independent: correlation within 5 / sqrt(N).
    assert abs(np.corrcoef(err[:, 0], err[:, 1])[0, 1]) < 5 / math.sqrt(N)


@pytest.mark.parametrize("p_drop", [0.02, 0.3, 0.9])
def test_gps_dropout_rate(p_drop):
    gte = GroundTruthError(GroundTruthErrorConfig(gps_dropout=p_drop, gps_sigma_m=(1, 1, 1)), seed=4)
    p = positions(N)
    out, valid = gte.gps(p)
    missing = N - valid.sum()
    assert abs(missing - N * p_drop) < 5 * math.sqrt(N * p_drop * (1 - p_drop))
    assert np.all(np.isfinite(out))
    assert gte.stats() == {"fixes": N, "fixes_dropped": missing}


def test_gps_dropout_independent_of_noise():
    gte = GroundTruthError(GroundTruthErrorConfig(gps_dropout=0.5, gps_sigma_m=(1, 1, 1)), seed=5)
    p = positions(N)
    out, valid = gte.gps(p)
    err = out - p
    # The noise of dropped and kept fixes has the same mean (5 sigma of the difference).
    diff = err[valid, 0].mean() - err[~valid, 0].mean()
    assert abs(diff) < 5 * math.sqrt(1 / valid.sum() + 1 / (~valid).sum())


def test_gps_dropout_extremes():
    p = positions(1000)
    gte = GroundTruthError(GroundTruthErrorConfig(gps_dropout=1.0), seed=1)
    out, valid = gte.gps(p)
    assert not valid.any() and np.array_equal(out, p)
    gte = GroundTruthError(GroundTruthErrorConfig(gps_dropout=0.0, gps_sigma_m=(1, 0, 0)), seed=1)
    assert gte.gps(p)[1].all()


def test_attitude_noise_is_body_side_with_the_configured_sigma():
    sigma_deg = 2.0
    cfg = GroundTruthErrorConfig(attitude_sigma_deg=sigma_deg)
    gte = GroundTruthError(cfg, seed=7, stream=2)
    q = unit_quats(N)
    out = gte.attitude(q)
    assert np.all(np.isfinite(out))
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", out, q) >= 0)  # same hemisphere as the input
    # Body-side error: R_true^-1 R_noisy is the noise rotation, in the body's own axes.
    r_true = Rotation.from_quat(q, scalar_first=True)
    body = (r_true.inv() * Rotation.from_quat(out, scalar_first=True)).as_rotvec()
    s = math.radians(sigma_deg)
    for axis in range(3):
        assert abs(body[:, axis].mean()) < 5 * s / math.sqrt(N)
        assert abs(body[:, axis].var(ddof=1) - s * s) < 5 * s * s * math.sqrt(2 / (N - 1))
    # And it is exactly sigma times the stream's normals (not the world-side composition).
    z = np.random.Generator(np.random.PCG64(np.random.SeedSequence(7, spawn_key=(0x47544552, 2, 1))))
    drawn = z.standard_normal((N, 3)) * s
    assert np.allclose(body, drawn, rtol=0, atol=1e-12)
    world = (Rotation.from_quat(out, scalar_first=True) * r_true.inv()).as_rotvec()
    assert not np.allclose(world, drawn, rtol=0, atol=1e-3)


def test_chunking_invariance_and_independent_streams():
    cfg = GroundTruthErrorConfig(gps_sigma_m=(1, 2, 3), gps_bias_m=(0, 0, 9), gps_dropout=0.2, attitude_sigma_deg=3)
    p, q = positions(500), unit_quats(500)
    whole = GroundTruthError(cfg, 11, 3)
    want_p, want_v = whole.gps(p)
    want_q = whole.attitude(q)
    parts = GroundTruthError(cfg, 11, 3)
    got_p, got_v, got_q = [], [], []
    rng = np.random.default_rng(0)
    lo = 0
    while lo < 500:
        hi = min(500, lo + int(rng.integers(1, 40)))
        # Interleave attitude and GPS calls: each has its own stream.
        got_q.append(parts.attitude(q[lo:hi]))
        a, b = parts.gps(p[lo:hi])
        got_p.append(a)
        got_v.append(b)
        lo = hi
    assert np.array_equal(np.concatenate(got_p), want_p)
    assert np.array_equal(np.concatenate(got_v), want_v)
    assert np.array_equal(np.concatenate(got_q), want_q)


def test_seeded_reproducibility_and_distinct_streams():
    cfg = GroundTruthErrorConfig(gps_sigma_m=(1, 1, 1), attitude_sigma_deg=1)
    p, q = positions(100), unit_quats(100)
    a = GroundTruthError(cfg, 5, 0)
    b = GroundTruthError(cfg, 5, 0)
    assert np.array_equal(a.gps(p)[0], b.gps(p)[0]) and np.array_equal(a.attitude(q), b.attitude(q))
    c = GroundTruthError(cfg, 5, 1)
    d = GroundTruthError(cfg, 6, 0)
    ref = GroundTruthError(cfg, 5, 0).gps(p)[0]
    assert not np.any(c.gps(p)[0] == ref) and not np.any(d.gps(p)[0] == ref)


def test_empty_batches():
    gte = GroundTruthError(GroundTruthErrorConfig(gps_sigma_m=(1, 1, 1), attitude_sigma_deg=1), 1)
    out, valid = gte.gps(np.zeros((0, 3)))
    assert out.shape == (0, 3) and valid.shape == (0,)
    assert gte.attitude(np.zeros((0, 4))).shape == (0, 4)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"gps_sigma_m": (1, -1, 0)}, "ground_truth_error.gps_sigma_m: must be 3 finite numbers >= 0 [east, north, up]"),
        ({"gps_sigma_m": (1, 1)}, "ground_truth_error.gps_sigma_m: must be 3 finite numbers >= 0"),
        ({"gps_bias_m": (0, float("inf"), 0)}, "ground_truth_error.gps_bias_m: must be 3 finite numbers [east, north, up]"),
        ({"gps_dropout": 1.5}, "ground_truth_error.gps_dropout: must be a probability in [0, 1], got 1.5"),
        ({"gps_dropout": float("nan")}, "ground_truth_error.gps_dropout: must be a probability in [0, 1], got nan"),
        ({"attitude_sigma_deg": -0.1}, "ground_truth_error.attitude_sigma_deg: must be in [0, 180), got -0.1"),
    ],
)
def test_config_rejects(kwargs, message):
    with pytest.raises(InputError) as err:
        GroundTruthErrorConfig(**kwargs)
    assert str(err.value).startswith(message)


def test_bad_inputs_are_named():
    gte = GroundTruthError(GroundTruthErrorConfig(attitude_sigma_deg=1), 1)
    with pytest.raises(PoseError, match="gps.position"):
        gte.gps([[0.0, np.nan, 0.0]])
    with pytest.raises(PoseError, match="attitude.orientation: quaternion of norm"):
        gte.attitude([[0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match=r"must be \(N, 4\)"):
        gte.attitude([[1.0, 0.0, 0.0]])


def test_attitude_stays_in_the_input_hemisphere_even_for_large_noise():
    # |rotation vector| > pi happens often at 120 deg per axis; the output sign is then
    # flipped so a stream of quaternions never jumps to the antipode.
    gte = GroundTruthError(GroundTruthErrorConfig(attitude_sigma_deg=120), 2)
    q = unit_quats(5000)
    out = gte.attitude(q)
    assert np.all(np.einsum("ij,ij->i", out, q) >= 0)
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0, rtol=0, atol=1e-12)
