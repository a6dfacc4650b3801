"""The optional pose errors of the real world (issue 28, Build item 2): heavy-tailed
horizontal GPS error (``--fit gps_outlier``: a share of rows whose horizontal GPS error is
from a wider component) and a constant mounting bias of the receiver's attitude
(``--fit mounting``: pitch and roll offsets). Off by default; each with a recovery test
on campaigns of the study's independent generator (tests/perf/study_campaigns.py)."""

import math
import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import repo_paths
from bench.fit import EIV_FREE, FitInputError, FitOptions, Params, fit
from bench.fit.csvio import parse_csv
from bench.fit.eiv import eiv_rows
from bench.fit.likelihood import GROSS_ERROR, Likelihood, rows_from_table
from bench.fit.rows import geometry, mounted

sys.path.insert(0, str(repo_paths.PERF))
import study_campaigns as sc  # noqa: E402

EXACT = ("kappa_eq", "r_en", "pose_sigma")
MOUNT = (3.0, -2.0)  # deg, the study generator's `mount` bias (pitch, roll)


def table_of(cond: sc.Condition, seed: int, rows=None):
    camp = sc.campaign(cond, seed)
    if rows is not None:
        camp.rows = rows(camp.rows)
    return parse_csv(camp.csv_text().encode(), f"{cond.name}-{seed}.csv"), camp.truth


def with_mount(rows, pitch_deg, roll_deg):
    """The logged attitude turned by the mounting bias in the body frame, as the study's
    ``mount`` pose error does it (logged = true * Ry(pitch) Rx(roll))."""
    out = rows.copy()
    rot = Rotation.from_quat(out[:, 8:12], scalar_first=True) * Rotation.from_euler("ZYX", [0.0, pitch_deg, roll_deg], degrees=True)
    out[:, 8:12] = rot.as_quat(scalar_first=True)
    return out


# -- the model ---------------------------------------------------------------------------


@pytest.mark.slow  # (1.3-1.4 s under load 8-10: the generator's walk, the pose moments)
def test_mounted_geometry_is_the_true_attitudes_geometry():
    table, _truth = table_of(sc.Condition("radial-exact", "radial", minutes=1), 3)
    true = rows_from_table(table).geo
    logged, _ = table_of(sc.Condition("radial-exact", "radial", minutes=1), 3, lambda r: with_mount(r, *MOUNT))
    geo = rows_from_table(logged).geo
    assert np.max(np.abs(geo.g - true.g)) > 0.02  # the bias moves the field direction
    back = mounted(geo, math.radians(MOUNT[0]), math.radians(MOUNT[1]))
    assert np.array_equal(back.log_r, true.log_r)
    np.testing.assert_allclose(back.g, true.g, rtol=0, atol=1e-8)  # (the CSV keeps 9 digits of each quaternion)


@pytest.mark.slow  # (1.3-1.4 s under load 8-10: the generator's walk, the pose moments)
def test_the_outlier_mixture_is_the_two_components_marginals():
    table, truth = table_of(sc.CONDITIONS["level-heavy"], 7)
    sigma0 = (1.0, 1.5, math.radians(2.0))
    rows, _ = eiv_rows(rows_from_table(table), table, sigma0)
    like = Likelihood(rows)
    p0 = Params(kappa_eq=truth.kappa_eq, r_en=truth.r_en, gps_sigma=1.0, attitude_sigma=sigma0[2], pose_sigma=1e-4)
    like.choose_regimes(p0)
    p = replace(p0, gps_outlier=0.2, gps_outlier_scale=3.0)
    usual, wide = p.outlier_components()
    assert usual == replace(p0, gps_outlier_scale=3.0) and wide.pose_error == (3.0, 1.5, sigma0[2])  # only the horizontal error widens
    prob = 0.8 * like.prob(p0) + 0.2 * like.prob(wide)
    expected = np.log((1.0 - GROSS_ERROR) * prob + GROSS_ERROR / (100.0 * p.r_outer + 2.0))
    assert np.array_equal(like.logp(p), expected)
    mix = 0.8 * like.prob_censored(p0) + 0.2 * like.prob_censored(wide)
    assert np.array_equal(like.prob_censored(p), mix, equal_nan=True)
    below = like.prob_below(p)
    # (to rounding: the components are clipped to [0, 1] one by one, the mixture once)
    np.testing.assert_allclose(below, 0.8 * like.prob_below(p0) + 0.2 * like.prob_below(wide), rtol=0, atol=1e-14)
    assert not np.array_equal(below, like.prob_below(p0))
    # the wide component's spread of log d is larger on every row, its vertical part unchanged
    assert np.all(like.pose_spread(wide, 0.0, 0.0)[0] > like.pose_spread(p0, 0.0, 0.0)[0])


@pytest.mark.slow  # (1.6-2.9 s under load: the campaign, the fit's checks)
def test_the_options_refuse_what_they_cannot_widen():
    table, _ = table_of(sc.Condition("radial-exact", "radial", minutes=1), 1)
    with pytest.raises(FitInputError, match="gps_outlier needs a horizontal GPS error"):
        fit(table, FitOptions(free=EXACT + ("gps_outlier",)))
    with pytest.raises(FitInputError, match="gps_outlier_scale needs gps_outlier"):
        fit(table, FitOptions(free=EIV_FREE + ("gps_outlier_scale",)))


# -- recovery ------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_mounting_bias_is_recovered_on_exact_poses():
    """Exact poses on the hand-held radial walk (tilts of 20 deg give the bias a lever):
    pitch and roll within their intervals and to a tenth of a degree, kappa_eq and r_en
    within theirs; without --fit mounting the same walk misses kappa_eq."""
    cond = sc.Condition("radial-exact", "radial", minutes=20)
    table, truth = table_of(cond, 4, lambda r: with_mount(r, *MOUNT))
    res = fit(table, FitOptions(free=EXACT + ("mount_pitch", "mount_roll")))
    assert res.converged, res.message
    for name, deg in zip(("mount_pitch", "mount_roll"), MOUNT):
        est, se = math.degrees(res.estimate[name]), math.degrees(res.se[name])
        assert abs(est - deg) < 2.58 * se and se < 0.1, (name, est, se)
    for name in ("kappa_eq", "r_en"):
        assert abs(res.estimate[name] - getattr(truth, name)) < 2.58 * res.se[name], name
    plain = fit(table, FitOptions(free=EXACT))
    assert abs(plain.estimate["kappa_eq"] - truth.kappa_eq) > 4 * plain.se["kappa_eq"]  # (4.7 s.e., r_en 197 +- 267 m)


@pytest.mark.slow
def test_a_mounting_bias_under_pose_error_is_covered():
    """The study's level-mount walk (Gauss-Markov GPS, 2 deg attitude error, +3 / -2 deg
    mounting), tuning seed 0: a level walk determines the bias only to a few degrees;
    the intervals cover it and the sign is right."""
    table, truth = table_of(sc.CONDITIONS["level-mount"], 0)
    res = fit(table, FitOptions(free=EIV_FREE + ("mount_pitch", "mount_roll")))
    assert res.converged, res.message
    for name, deg in zip(("mount_pitch", "mount_roll"), MOUNT):
        est, se = math.degrees(res.estimate[name]), math.degrees(res.se[name])
        assert abs(est - deg) < 1.96 * se and se < 4.0 and est * deg > 0, (name, est, se)
    for name in ("kappa_eq", "r_en"):
        assert abs(res.estimate[name] - getattr(truth, name)) < 1.96 * res.se[name], name


@pytest.mark.slow
def test_heavy_tailed_gps_error_is_recovered_and_the_check_goes_quiet():
    """The study's level-heavy walk (Gauss-Markov GPS plus multipath jumps of 3-5 m for
    10-60 s, about a quarter of the time), tuning seed 0: the default fit's goodness-of-fit
    check fires (a Gaussian compromise); with --fit gps_outlier it is quiet, kappa_eq and
    r_en are within their intervals and the outlier share and width are those of the jumps."""
    table, truth = table_of(sc.CONDITIONS["level-heavy"], 0)
    plain = fit(table, FitOptions(free=EIV_FREE))
    assert plain.converged and not plain.goodness_of_fit.fits
    res = fit(table, FitOptions(free=EIV_FREE + ("gps_outlier", "gps_outlier_scale")))
    assert res.converged, res.message
    assert res.goodness_of_fit.fits and res.goodness_of_fit.p_value > 0.5
    for name in ("kappa_eq", "r_en"):
        assert abs(res.estimate[name] - getattr(truth, name)) < 1.96 * res.se[name], name
    assert 0.15 < res.estimate["gps_outlier"] < 0.8 and 2.0 < res.estimate["gps_outlier_scale"] < 6.0
    assert res.se["kappa_eq"] < plain.se["kappa_eq"]


@pytest.mark.slow
def test_without_heavy_tails_the_outlier_width_collapses():
    """Gauss-Markov GPS error only (level-gm, tuning seed 0): no wide component distinct
    from the usual one; the fit converges with the width on its floor and says so, and
    kappa_eq stays within its interval."""
    table, truth = table_of(sc.CONDITIONS["level-gm"], 0)
    res = fit(table, FitOptions(free=EIV_FREE + ("gps_outlier", "gps_outlier_scale")))
    assert res.converged, res.message
    assert res.estimate["gps_outlier_scale"] == 1.5 or res.estimate["gps_outlier"] == 1e-5
    assert any("no outliers wider" in n or "no GPS outliers are visible" in n for n in res.notes)
    assert abs(res.estimate["kappa_eq"] - truth.kappa_eq) < 1.96 * res.se["kappa_eq"]


# -- the command line ----------------------------------------------------------------------


def fit_options(*argv):
    import argparse

    from bench.fit.cli import options_from_args, register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    return options_from_args(parser.parse_args(["fit", "walk.csv", *argv]))


def test_the_command_line_names_free_both_parameters_of_each():
    assert fit_options().free == ("kappa_eq", "r_en", "gps_sigma", "attitude_sigma")
    assert fit_options("--fit", "gps_outlier").free == (
        "kappa_eq", "r_en", "gps_sigma", "attitude_sigma", "gps_outlier", "gps_outlier_scale",
    )  # fmt: skip
    assert fit_options("--fit", "mounting,gps_outlier", "--gps-sigma", "1").free == (
        "kappa_eq", "r_en", "attitude_sigma", "gps_outlier", "gps_outlier_scale", "mount_pitch", "mount_roll",
    )  # fmt: skip
    assert fit_options("--fit", "mounting", "--gps-sigma", "0", "--attitude-sigma", "0").free == (
        "kappa_eq", "r_en", "pose_sigma", "mount_pitch", "mount_roll",
    )  # fmt: skip


@pytest.mark.slow  # (1.6-2.9 s under load: the campaign, the fit's checks)
def test_the_command_line_refuses_outliers_of_exact_positions(capsys, tmp_path):
    from bench.cli import main

    table, _ = table_of(sc.Condition("radial-exact", "radial", minutes=1), 1)
    path = tmp_path / "walk.csv"
    table.write_csv(path)
    assert main(["fit", str(path), "--fit", "gps_outlier", "--gps-sigma", "0"]) == 2
    out, err = capsys.readouterr()
    assert (out, err) == ("", "arva-bench: fit: --fit gps_outlier needs a GPS error to widen, not --gps-sigma 0\n")


@pytest.mark.slow  # (three fits of a 10-minute campaign)
def test_an_outlier_fit_that_does_not_converge_gives_the_fit_without_it(monkeypatch):
    """When the fit with heavy-tailed GPS error stops (on mild tails the mixture has no
    clear second component), the numbers are those of the fit without it, converged,
    with a first note naming why; the time and evaluations of both are counted."""
    from bench.fit import estimate

    table, _truth = table_of(sc.Condition("level-gm", "level_rw", "gm", minutes=10), 1)
    real = estimate.fit_restarted
    stuck = []

    def stalls_with_outliers(table, options):
        res = real(table, options)
        if "gps_outlier" in options.free:
            stuck.append(res.n_evals)
            res = replace(res, converged=False, message="no convergence after 60 Newton iterations")
        return res

    monkeypatch.setattr(estimate, "fit_restarted", stalls_with_outliers)
    res = fit(table, FitOptions(free=EIV_FREE + ("gps_outlier", "gps_outlier_scale")))
    plain = fit(table, FitOptions(free=EIV_FREE))
    assert res.converged and res.free == plain.free == EIV_FREE and res.params.gps_outlier == 0.0
    assert res.notes[0] == (
        "the fit with heavy-tailed GPS error (--fit gps_outlier) did not converge (no convergence after 60 Newton "
        "iterations); these are the numbers without it (no share of wider GPS errors)"
    )
    assert res.notes[1:] == plain.notes
    for name in EIV_FREE:  # (a s.e. is nan for a parameter held on its floor)
        assert np.array_equal([res.estimate[name], res.se[name]], [plain.estimate[name], plain.se[name]], equal_nan=True), name
    assert len(stuck) == 1 and res.n_evals == plain.n_evals + stuck[0]
