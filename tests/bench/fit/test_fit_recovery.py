"""Recovery of the receiver model from campaigns emulated by our own emulator.

Fixed seeds make every test deterministic; the thresholds are set from the sampling
distributions measured in docs/calibration.md, with room for them to hold on any seed
rather than on these seeds only.
"""

import math

import numpy as np
import pytest

from fit_campaign import Walk, emulate_campaign
from bench.fit.estimate import fit_table
from bench.fit.result import FitOptions
from bench.fit.likelihood import Params
from emulator.receiver.model import ModelParams

PAIRS = [(1.542, 80.0), (1.2, 60.0), (2.0, 120.0), (1.542, 40.0)]


@pytest.mark.parametrize(("kappa", "r_en"), PAIRS)
def test_recovers_kappa_within_2_percent_and_r_en_within_10_percent(kappa, r_en):
    for seed in range(3):
        res = fit_table(emulate_campaign(20, ModelParams(kappa_eq=kappa, r_en=r_en), seed=seed))
        assert res.converged, res.message
        assert abs(res.estimate["kappa_eq"] / kappa - 1) < 0.02
        assert abs(res.estimate["r_en"] / r_en - 1) < 0.10
        # Much tighter than required: the brief's 1 % and 5 % hold already at 20 minutes.
        assert abs(res.estimate["kappa_eq"] / kappa - 1) < 0.01 and abs(res.estimate["r_en"] / r_en - 1) < 0.05
        assert res.n_rows == 1200 and res.n_censored == int(np.sum(res.n_censored))


@pytest.mark.slow
def test_standard_errors_are_consistent_with_the_spread_over_seeds():
    """Coverage over 20 seeds: if the standard errors were honest, |estimate - truth| / se
    would exceed 2 in ~5 % of fits; P(more than 4 of 20 | p = 0.05) = 0.3 %, so >= 80 %
    within 2 se is a check that fails only for wrong (too small) standard errors. The
    root mean square of z must also not be far below 1 (standard errors far too big)."""
    kappa, r_en = 1.542, 80.0
    z = []
    for seed in range(20):
        res = fit_table(emulate_campaign(20, ModelParams(kappa_eq=kappa, r_en=r_en), seed=100 + seed))
        assert res.converged, res.message
        z.append([(res.estimate["kappa_eq"] - kappa) / res.se["kappa_eq"], (res.estimate["r_en"] - r_en) / res.se["r_en"]])
    z = np.array(z)
    within = np.mean(np.abs(z) < 2.0, axis=0)
    rms = np.sqrt(np.mean(z * z, axis=0))
    assert np.all(within >= 0.80), within
    assert np.all((rms > 0.5) & (rms < 1.6)), rms


def test_naive_regression_is_biased_near_the_range_limit_and_ours_is_not():
    """Walking only from 30 to 65 m: most detections are noise-assisted, so least squares
    on the detected rows (dropping the -1 rows) underestimates kappa_eq."""
    walk = Walk(r_min=30.0, r_max=65.0)
    ours, naive = [], []
    for seed in range(3):
        res = fit_table(emulate_campaign(20, ModelParams(), seed=seed, walk=walk))
        assert res.converged and res.n_censored > 400
        ours.append(res.estimate["kappa_eq"] / 1.542 - 1)
        naive.append(res.naive["kappa_eq"] / 1.542 - 1)
    assert max(abs(v) for v in ours) < 0.003
    assert all(v < -0.012 for v in naive)
    assert abs(np.mean(naive)) > 5 * max(abs(v) for v in ours)


def test_no_noise_in_the_data_does_not_converge():
    from bench.fit.table import Table
    from emulator.receiver.model import measure

    tab = emulate_campaign(10, ModelParams(), seed=1)
    clean = measure(tab.rx_pos, tab.rx_quat, tab.tx_pos[:1], tab.tx_quat[:1], ModelParams()).d[:, 0]
    res = fit_table(Table.from_columns("clean", tab.t, tab.seq, tab.id, clean, tab.delta, tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat))
    assert not res.converged
    assert res.message == "r_en runs to its upper bound 10000 (the data show no noise floor)"


def test_pose_sigma_is_estimated_when_the_poses_are_noisy():
    from bench.fit.likelihood import geometry, simulate
    from bench.fit.table import Table

    tab = emulate_campaign(20, ModelParams(), seed=3)
    geo = geometry(tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat)
    d = simulate(geo, Params(pose_sigma=0.01), np.random.default_rng(3))
    noisy = Table.from_columns("noisy", tab.t, tab.seq, tab.id, d, tab.delta, tab.rx_pos, tab.rx_quat, tab.tx_pos, tab.tx_quat)
    res = fit_table(noisy)
    assert res.converged, res.message
    assert abs(res.estimate["pose_sigma"] / 0.01 - 1) < 3 * res.se["pose_sigma"] / 0.01 + 0.05
    assert abs(res.estimate["kappa_eq"] / 1.542 - 1) < 0.01 and abs(res.estimate["r_en"] / 80 - 1) < 0.05
    fixed = fit_table(noisy, FitOptions(free=("kappa_eq", "r_en"), base=Params(pose_sigma=1e-4)))
    assert fixed.log_likelihood < res.log_likelihood - 100  # exact poses do not fit these data


@pytest.mark.slow
def test_optional_parameters():
    # r_outer: the receiver shows at most 40 m.
    res = fit_table(emulate_campaign(20, ModelParams(r_outer=40.0), seed=1), FitOptions(free=("kappa_eq", "r_en", "r_outer", "pose_sigma")))
    assert res.converged and abs(res.estimate["r_outer"] - 40.0) < 0.1 and 0 < res.se["r_outer"] < 0.1
    # q: the y antenna picks up 60 % of the x antenna's noise.
    res = fit_table(emulate_campaign(20, ModelParams(q=(1.0, 0.6, 1.0)), seed=2), FitOptions(free=("kappa_eq", "r_en", "q", "pose_sigma")))
    assert res.converged and abs(res.estimate["q"] - 0.6) < 0.1 and res.params.q[0] == 1.0


def test_time_offset_is_recovered():
    from bench.fit.table import Table
    from emulator.receiver.noise import NoiseEffect
    from emulator.receiver.model import measure
    from fit_campaign import walk_poses

    walk = Walk(wobble_sd=0.0)  # a smooth path: the track between samples is the truth
    n, delta = 900, 0.7
    t = np.arange(n, dtype=float)
    p_true, q_true = walk_poses(t, walk, np.random.default_rng(2))
    p_log, q_log = walk_poses(t - delta, walk, np.random.default_rng(2))  # logged poses lag 0.7 s
    txp, txq = np.array([[0.0, 0.0, -1.0]]), np.array([[0.9, 0.1, 0.3, 0.2]])
    d = measure(p_true, q_true, txp, txq, ModelParams(), noise=NoiseEffect(2).draw(n, 1)).d[:, 0]
    tab = Table.from_columns("lag", t, np.arange(n), np.where(d == -1, -1, 1), d, np.zeros(n), p_log, q_log, np.repeat(txp, n, 0), np.repeat(txq, n, 0))
    res = fit_table(tab, FitOptions(free=("kappa_eq", "r_en", "time_offset", "pose_sigma")))
    assert res.converged, res.message
    # Within 0.05 s: the walk turns round and changes its hold at leg ends, which splines
    # through 1 Hz poses cannot follow exactly.
    assert abs(res.estimate["time_offset"] - delta) < 0.05
    # The interpolation error at the leg ends shows up as a pose error of ~1 %, which
    # costs r_en some accuracy; the thresholds still hold.
    assert abs(res.estimate["kappa_eq"] / 1.542 - 1) < 0.02 and abs(res.estimate["r_en"] / 80 - 1) < 0.10
    assert math.isfinite(res.se["time_offset"])
