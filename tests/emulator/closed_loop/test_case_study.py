"""The paper's case study (section IV, Figs. 8-11) in closed loop, deterministic.

What the paper reports, for all four tests: the UAV reaches the transmitter following
the flux lines, and the distance "shows a limited growth before decreasing to small
values close to zero", most evidently in the fourth test.
"""

import subprocess
import sys

import numpy as np
import pytest
import serial

import emulator.urlhandler  # noqa: F401  (registers arvaemu://)
from emulator.closed_loop.case_study import CASES, load_case, main, run_case, scene_path, summarize

R_S = 1.0

# Pinned results of the seeded runs (range-sensor noise included): time located (s),
# growth max/start of the 3-D distance, horizontal error (m).
FLUX = {1: (46.0, 1.0822, 0.6971), 2: (28.0, 1.1313, 0.6922), 3: (59.0, 1.0700, 0.6903), 4: (55.0, 2.2850, 0.6966)}
RESCUER = {1: (57.9, 0.3034), 2: (52.8, 0.2154), 3: (70.8, 0.2573), 4: (53.8, 0.0702)}


@pytest.fixture(scope="module")
def flux_runs():
    return {case: run_case(case, "flux") for case in CASES}


def test_scenes_are_the_papers_four_cases():
    for case, (position, _yaw) in CASES.items():
        scene = load_case(case)
        assert scene.transmitters[0].trajectory.positions[0].tolist() == list(position)
        v = scene.receivers[0].vehicle
        assert (v.start, v.v_max, v.r_s, v.controller) == ((0.0, 0.0), 1.0, 1.0, "flux")
        # The transmitter lies on the snow surface of the shared DEM.
        assert v.terrain.height(*position[:2]) == pytest.approx(position[2], abs=1e-4)


@pytest.mark.parametrize("case", sorted(CASES))
def test_flux_follower_reaches_the_transmitter(flux_runs, case):
    r = flux_runs[case]
    s = summarize(case, r)
    t_loc, growth, error = FLUX[case]
    assert s["located"] and s["t_located_s"] == pytest.approx(t_loc, abs=1e-9)
    assert s["error_m"] == pytest.approx(error, abs=1e-4)
    assert s["error_m"] <= R_S  # within r_s of the transmitter's ground projection
    assert s["final_horizontal_m"] <= R_S
    assert s["final_m"] < 1.25  # r_s above it, dz / sqrt(2) aside: "close to zero"


@pytest.mark.parametrize("case", sorted(CASES))
def test_distance_first_grows_a_little_then_falls(flux_runs, case):
    r = flux_runs[case]
    dist = r.distance(0)
    i_max = int(np.argmax(dist))
    growth = dist[i_max] / dist[0]
    assert growth == pytest.approx(FLUX[case][1], abs=1e-4)
    assert dist[i_max] > dist[0] + 1.0  # it grows ...
    assert 0 < r.t[i_max] < r.located[0].t / 2  # ... early on ...
    assert np.all(np.diff(dist[i_max:]) < 0.01)  # ... then only falls,
    assert dist[-1] < dist[0] / 5  # to close to zero


def test_growth_is_most_evident_in_the_fourth_test(flux_runs):
    growth = {case: summarize(case, r)["growth"] for case, r in flux_runs.items()}
    assert max(growth, key=growth.get) == 4
    assert growth[4] > 2 and all(1.05 < growth[c] < 1.2 for c in (1, 2, 3))


@pytest.mark.parametrize("case", sorted(CASES))
def test_receiver_only_strategy_also_finds_it(case):
    s = summarize(case, run_case(case, "receiver_only"))
    t_loc, error = RESCUER[case]
    assert s["located"] and s["t_located_s"] == pytest.approx(t_loc, abs=1e-9)
    assert s["error_m"] == pytest.approx(error, abs=1e-4)
    assert s["error_m"] < 0.5  # bracketing beats the flux follower's dz / sqrt(2)


def test_orientation_matters_start_behind_the_dipole_never_grows():
    # Case 1 with its dipole pointing east, away from the start: straight in.
    from dataclasses import replace

    from emulator.closed_loop.loop import ClosedLoop
    from emulator.frames.trajectory import Trajectory

    scene = load_case(1)

    tx = scene.transmitters[0]
    tx = replace(tx, trajectory=Trajectory.static(tx.trajectory.positions[0], [1.0, 0.0, 0.0, 0.0]))
    r = ClosedLoop(replace(scene, transmitters=(tx,))).run(300.0)
    dist = r.distance(0)
    assert dist.max() <= dist[0] + 1e-9 and r.located


@pytest.mark.slow
def test_plots_like_figs_8_to_11(tmp_path, capsys):
    assert main(["--controllers", "flux", "--out", str(tmp_path)]) == 0
    for case in CASES:
        png = tmp_path / f"case_study_{case}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    table = capsys.readouterr().out
    assert "| 4 | flux | 8.77 | 20.05 (20.0) | 2.285 | 55.0 | 0.697 | 1.21 |" in table


@pytest.mark.subprocess
def test_closed_loop_stream_on_stdout_matches_the_in_process_port():
    """The closed-loop receiver's $PARVA goes out through the scheduler (batches of 4096
    epochs) and the arvaemu:// port (epoch by epoch) byte for byte, and says what the
    run saw: far at first, then the inner zone over the transmitter."""
    scene = str(scene_path(4))
    out = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--scene", scene, "--port", "-", "--frames", "80", "--speed", "0"],
        capture_output=True,
        timeout=60,
        check=True,
    ).stdout
    with serial.serial_for_url(f"arvaemu://{scene}?speed=0&frames=80", timeout=2) as port:
        assert port.read(len(out) + 100) == out
    d = [int(line.split(b",")[5]) for line in out.splitlines()]
    from emulator.closed_loop.loop import ClosedLoop

    run = ClosedLoop(load_case(4)).run(80.0, stop_when_found=False)  # hovers once located
    assert len(d) == 80 and d == run.d[:, 0].tolist()
    assert d[0] == 945 and max(d) > 2000 and all(0 <= v <= 300 for v in d[-20:])


@pytest.mark.subprocess
def test_plots_without_matplotlib_say_which_extra_before_flying(tmp_path):
    from without_extra import run_without

    p = run_without("matplotlib", "emulator.closed_loop.case_study:main", ["--out", str(tmp_path)])
    assert (p.returncode, p.stdout) == (2, "")
    assert p.stderr == (
        "python -m emulator.closed_loop.case_study: case-study plots (--out) needs matplotlib "
        "(install the extra: pip install 'arva-bench[plot]')\n"
    )


@pytest.mark.parametrize("value, item", [("flux,nope", "'nope'"), ("flux,", "''")])
def test_an_unknown_controller_is_one_line_before_flying(capsys, value, item):
    with pytest.raises(SystemExit) as exc:
        main(["--controllers", value])
    out, err = capsys.readouterr()
    assert (exc.value.code, out) == (2, "")
    assert err == (
        "python -m emulator.closed_loop.case_study: error: argument --controllers: "
        f"unknown controller {item} (choose from flux, receiver_only)\n"
    )
