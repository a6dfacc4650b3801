"""The dropout probability (issue 28, Build item 3): a row reads -1 with probability
``dropout`` whatever the signal, so a few spurious "nothing heard" rows are explained as
such instead of pulling r_en (``--fit dropout``)."""

import json

import numpy as np
import pytest

from bench.cli import main
from bench.fit import FitOptions, fit
from bench.fit.likelihood import GROSS_ERROR, Likelihood, Params, rows_from_table, simulate
from emulator.receiver.model import ModelParams
from fit_campaign import emulate_campaign

TRUTH = ModelParams(kappa_eq=1.48, r_en=80.0)
EXACT = ("kappa_eq", "r_en", "pose_sigma")


def spurious(table, fraction=0.02, seed=100):
    """``fraction`` of the detected rows turned into -1 rows (their id and delta too)."""
    rng = np.random.default_rng(seed)
    det = np.flatnonzero(table.d != -1)
    idx = rng.choice(det, int(fraction * det.size), replace=False)
    table.d[idx], table.id[idx], table.delta[idx] = -1, -1, -1
    return idx


def test_the_likelihood_mixes_a_minus_one_with_the_dropout_probability():
    table = emulate_campaign(5, TRUTH, seed=1)
    like = Likelihood(rows_from_table(table))
    p0 = Params(kappa_eq=1.48, r_en=80.0, pose_sigma=1e-3)
    like.choose_regimes(p0)
    p = Params(kappa_eq=1.48, r_en=80.0, pose_sigma=1e-3, dropout=0.03)
    prob = 0.97 * like.prob(p0) + 0.03 * (table.d == -1)
    expected = np.log((1.0 - GROSS_ERROR) * prob + GROSS_ERROR / (100.0 * p.r_outer + 2.0))
    assert np.array_equal(like.logp(p), expected)
    assert np.array_equal(like.prob_censored(p), 0.97 * like.prob_censored(p0) + 0.03)
    assert not like.has_grad(p) and like.has_grad(p0)  # (its derivative is by differences)


def test_simulated_dropouts_only_turn_rows_into_minus_one():
    table = emulate_campaign(0, TRUTH, seed=2, n_rows=4000)
    geo = rows_from_table(table).geo
    p0 = Params(kappa_eq=1.48, r_en=80.0, pose_sigma=1e-3)
    plain = simulate(geo, p0, np.random.default_rng(5))
    dropped = simulate(geo, Params(kappa_eq=1.48, r_en=80.0, pose_sigma=1e-3, dropout=0.05), np.random.default_rng(5))
    changed = dropped != plain
    assert np.all(dropped[changed] == -1)
    n = int(np.sum(plain != -1))
    assert abs(int(changed.sum()) - 0.05 * n) < 4 * np.sqrt(0.05 * 0.95 * n)


def test_spurious_minus_ones_are_estimated_as_dropout():
    table = emulate_campaign(60, TRUTH, seed=0)
    spurious(table)
    res = fit(table, FitOptions(free=EXACT + ("dropout",)))
    assert res.converged
    assert abs(res.estimate["dropout"] - 0.02) < 3 * res.se["dropout"] and res.se["dropout"] < 0.005
    for name, truth in (("kappa_eq", TRUTH.kappa_eq), ("r_en", TRUTH.r_en)):
        assert abs(res.estimate[name] - truth) < 3 * res.se[name], name


def test_on_a_clean_campaign_the_dropout_goes_to_its_floor():
    table = emulate_campaign(60, TRUTH, seed=0)
    plain = fit(table, FitOptions(free=EXACT))
    res = fit(table, FitOptions(free=EXACT + ("dropout",)))
    assert res.converged and res.estimate["dropout"] == 1e-5
    assert "dropout is at its lower bound 1e-05 (no spurious -1 rows are visible); the other standard errors hold it there" in res.notes
    for name in ("kappa_eq", "r_en"):
        assert abs(res.estimate[name] - plain.estimate[name]) < 0.01 * plain.se[name], name
        assert res.se[name] == pytest.approx(plain.se[name], rel=0.01), name


@pytest.mark.slow
def test_the_command_line_fits_it(capsys, tmp_path):
    table = emulate_campaign(30, TRUTH, seed=3)
    spurious(table)
    path = tmp_path / "walk.csv"
    table.write_csv(path)
    exact = ["--gps-sigma", "0", "--attitude-sigma", "0"]
    assert main(["fit", str(path), "--json", "--fit", "dropout", *exact]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "dropout" in out["free"] and 0.005 < out["dropout"] < 0.05 and out["dropout_se"] > 0
    assert main(["fit", str(path), "--fit", "dropout", *exact]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("dropout")]
    assert len(line) == 1 and line[0].endswith("   (rows that read -1 whatever the signal)")


def test_the_default_fit_refits_with_dropout_when_the_check_names_spurious_rows():
    table = emulate_campaign(60, TRUTH, seed=0)
    spurious(table)
    plain = fit(table, FitOptions(free=EXACT, spurious_refit=False))
    gof = plain.goodness_of_fit
    assert "dropout" not in plain.free and gof.p_unexpected < 0.01
    assert any(n.startswith(f"the model does not describe this walk: {gof.unexpected_censored} rows say") for n in plain.notes)
    res = fit(table, FitOptions(free=EXACT))
    given = fit(table, FitOptions(free=EXACT + ("dropout",)))
    assert res.free == given.free and res.estimate == given.estimate
    np.testing.assert_equal(res.se, given.se)  # (pose_sigma on its bound: nan on both)
    assert res.notes[0] == (
        f"spurious -1 rows: {gof.unexpected_censored} rows say 'nothing heard' where the model gives that less than "
        f"0.1 % chance ({gof.expected_unexpected:.2g} expected), which pulls r_en low (it was "
        f"{plain.estimate['r_en']:.5g}); refitted with a dropout probability (as --fit dropout): "
        f"{100 * given.estimate['dropout']:.2g} % of rows read -1 whatever the signal"
    )
    assert res.notes[1:] == given.notes
    assert res.n_evals > given.n_evals  # (the first fit's cost is counted)


def test_a_clean_campaign_is_not_refitted():
    table = emulate_campaign(60, TRUTH, seed=0)
    res = fit(table, FitOptions(free=EXACT))
    assert res.goodness_of_fit.p_unexpected >= 0.01 and "dropout" not in res.free
