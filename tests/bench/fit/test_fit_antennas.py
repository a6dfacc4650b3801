"""The fit with the receiver class: a 2-antenna campaign is fitted with --antennas 2,
and the class travels into the written scene."""

import numpy as np
import pytest

from fit_campaign import emulate_campaign
from bench.fit.estimate import fit_table
from bench.fit.result import FitOptions
from bench.fit.likelihood import Geometry, Params, simulate
from bench.fit.scene import write_scene
from bench.fit.table import FitInputError
from emulator.receiver.model import ModelParams, measure
from emulator.scene.reader import load_scene


@pytest.fixture(scope="module")
def two_antenna_campaign():
    return emulate_campaign(20, ModelParams(kappa_eq=1.542, r_en=80.0, antennas=2), seed=1)


@pytest.fixture(scope="module")
def fitted(two_antenna_campaign):
    return fit_table(two_antenna_campaign, FitOptions(base=Params(antennas=2)))


def test_recovers_a_two_antenna_receiver(fitted):
    assert fitted.converged, fitted.message
    assert abs(fitted.estimate["kappa_eq"] / 1.542 - 1) < 0.02
    assert abs(fitted.estimate["r_en"] / 80.0 - 1) < 0.10
    assert fitted.to_json()["antennas"] == 2


def test_the_wrong_class_fits_worse(two_antenna_campaign, fitted):
    wrong = fit_table(two_antenna_campaign, FitOptions(base=Params(antennas=3)))
    assert wrong.log_likelihood < fitted.log_likelihood - 10


def test_simulate_matches_the_emulator_with_two_antennas():
    rng = np.random.default_rng(4)
    n = 400
    rx = rng.uniform(-6, 6, (n, 3))
    q = rng.standard_normal((n, 4))
    tx_q = rng.standard_normal((n, 4))
    from bench.fit.likelihood import geometry

    geo = geometry(rx, q, np.zeros((n, 3)), tx_q)
    p = Params(pose_sigma=0.0, r_en=1e9, antennas=2)  # noise negligibly small
    d_fit = simulate(geo, p, np.random.default_rng(0))
    d_emu = np.array([measure(rx[i : i + 1], q[i : i + 1], np.zeros((1, 3)), tx_q[i : i + 1], ModelParams(antennas=2)).d[0, 0] for i in range(n)])
    assert isinstance(geo, Geometry)
    assert d_fit.tolist() == d_emu.tolist()


def test_scene_gets_the_class(fitted, tmp_path):
    new = tmp_path / "fitted.toml"
    assert write_scene(new, fitted) == "created"
    assert load_scene(new).receiver_model().antennas == 2
    other = tmp_path / "three.toml"
    other.write_text("spec = 1\n[[transmitters]]\nid = 1\nposition = [0.0, 0.0, 0.0]\n[receiver]\nposition = [5.0, 0.0, 0.0]\n")
    before = other.read_text()
    with pytest.raises(FitInputError, match=r"its receiver has 3 antennas, the fit assumed 2 \(--antennas\); set \[receiver\] antennas"):
        write_scene(other, fitted)
    assert other.read_text() == before  # restored


def test_command_line_option():
    from bench.cli import parse_args
    from bench.fit.cli import options_from_args

    assert options_from_args(parse_args(["fit", "x.csv", "--antennas", "2"])).base.antennas == 2
    assert options_from_args(parse_args(["fit", "x.csv"])).base.antennas == 3
    with pytest.raises(SystemExit) as exc:
        parse_args(["fit", "x.csv", "--antennas", "1"])
    assert exc.value.code == 2
