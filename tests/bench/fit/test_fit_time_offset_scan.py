"""The time offset between the receiver and the pose streams, estimated by default (issue 15).

With the errors-in-variables model and the offset neither fitted (``--fit time_offset``)
nor given (``--time-offset SEC``), the fit scans offsets of +-3 s at its estimate on a
seeded subsample and fits the offset when the poses fit clearly better at one
(:data:`bench.fit.offset.OFFSET_GAIN` nats); either way one note says what it found. The
campaigns here log their poses late by a known offset (``PoseError.time_offset``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from bench.cli import main
from bench.fit.estimate import fit_table
from bench.fit.offset import OFFSET_GAIN, offset_scan
from bench.fit.result import FitOptions
from bench.fit.likelihood import Params
from emulator.receiver.model import ModelParams
from fit_campaign import PoseError, emulate_campaign

TRUTH = ModelParams(kappa_eq=1.542, r_en=80.0)
#: the sigmas given (one Newton pass per fit: seconds, not tens of seconds)
BASE = Params(gps_sigma=1.0, gps_ratio=1.5, attitude_sigma=math.radians(2.0))
GIVEN = FitOptions(free=("kappa_eq", "r_en"), base=BASE)


def campaign(offset: float, minutes: float = 30, seed: int = 1):
    pe = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0, time_offset=offset)
    return emulate_campaign(minutes, TRUTH, seed=seed, pose_error=pe)


@pytest.mark.slow
def test_a_one_second_offset_is_found_and_fitted():
    res = fit_table(campaign(1.0), GIVEN)
    assert res.converged
    assert res.free == ("kappa_eq", "r_en", "time_offset")
    off, se = res.estimate["time_offset"], res.se["time_offset"]
    # s.e. 0.206 s (0.19 s before the sandwich's fixed-b scale, covariance.fixed_b_scale)
    assert abs(off - 1.0) < 3 * se and se < 0.25, (off, se)
    assert res.notes[0].startswith("time offset: on ") and " rows the poses fit " in res.notes[0]
    assert "so it was fitted; --time-offset SEC gives it instead" in res.notes[0]
    assert abs(res.estimate["kappa_eq"] / 1.542 - 1) < 0.02


def test_no_offset_none_found_and_the_fit_is_the_unscanned_one():
    table = campaign(0.0)
    res = fit_table(table, GIVEN)
    plain = fit_table(table, replace(GIVEN, scan_offset=False))
    assert res.free == plain.free == ("kappa_eq", "r_en")
    assert res.estimate == plain.estimate and res.se == plain.se  # the scan only adds its note
    (note,) = [n for n in res.notes if n.startswith("time offset")]
    assert note.startswith("time offset: none found (a scan over +-3 s on ")
    assert note.endswith(f"below {OFFSET_GAIN:g}); held at 0 s: --fit time_offset fits it anyway")
    assert [n for n in plain.notes if n.startswith("time offset")] == []


def test_the_scan_locates_the_offset_and_scores_it():
    table = campaign(0.5)
    at = replace(BASE, kappa_eq=1.542, r_en=80.0)
    scan = offset_scan(table, at, GIVEN)
    assert scan.rows <= len(table)
    assert abs(scan.offset - 0.5) < 0.15 and scan.gain > OFFSET_GAIN
    none = offset_scan(campaign(0.0), at, GIVEN)
    assert abs(none.offset) < 0.2 and 0.0 <= none.gain < OFFSET_GAIN
    # seeded: the same subsample, the same numbers
    again = offset_scan(table, at, GIVEN)
    assert (again.offset, again.gain, again.rows) == (scan.offset, scan.gain, scan.rows)


@pytest.mark.slow
def test_freeing_the_offset_at_zero_does_not_move_kappa_eq():
    """The track the offset moves along holds the shrunk (expected true) positions, as
    the geometry at offset 0 does. With the logged positions there any offset but 0 took
    the shrinkage away: freeing the offset on this campaign moved kappa_eq by more than
    one standard error."""
    table = campaign(0.0, minutes=60, seed=5)
    held = fit_table(table, replace(GIVEN, scan_offset=False))
    freed = fit_table(table, replace(GIVEN, free=("kappa_eq", "r_en", "time_offset")))
    assert abs(freed.estimate["time_offset"]) < 2 * freed.se["time_offset"]
    assert abs(freed.estimate["kappa_eq"] - held.estimate["kappa_eq"]) < 0.25 * held.se["kappa_eq"]


def test_not_scanned_when_given_fitted_or_exact(tmp_path, capsys):
    table = campaign(1.0, minutes=10)
    path = tmp_path / "late.csv"
    table.write_csv(path)
    assert main(["fit", str(path), "--gps-sigma", "1,1.5", "--attitude-sigma", "2", "--time-offset", "0"]) == 0
    out = capsys.readouterr().out
    assert "time offset" not in out and "time_offset" not in out
    assert main(["fit", str(path), "--gps-sigma", "1,1.5", "--attitude-sigma", "2"]) == 0
    out = capsys.readouterr().out
    assert "time_offset =" in out and "note: time offset: on " in out
    exact = fit_table(table, FitOptions(free=("kappa_eq", "r_en", "pose_sigma")))  # poses declared exact
    assert not [n for n in exact.notes if n.startswith("time offset")] and "time_offset" not in exact.free
