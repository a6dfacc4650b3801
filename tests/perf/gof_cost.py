"""What the fit's goodness-of-fit check (bench/fit/diagnostics.py) costs: the same 1e5-row
fit (``tests/fit_campaign.py``, seed 1000) with and without it, alternating, wall and CPU
of the fit's process, with the load average at the start of each fit, and the time spent
in the check itself.

Usage: python tests/perf/gof_cost.py exact|pose-error ROUNDS
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent), str(HERE.parents[1])]

import bench.fit.estimate as est  # noqa: E402
from bench.fit import EIV_FREE, FitOptions, fit  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402
from fit_campaign import PoseError, emulate_campaign  # noqa: E402


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=("exact", "pose-error"))
    ap.add_argument("rounds", type=int, help="fits with and without the check, alternating")
    args = ap.parse_args(argv)
    kind, rounds = args.kind, args.rounds
    truth = ModelParams(kappa_eq=1.542, r_en=80.0)
    if kind == "exact":
        table, opts = emulate_campaign(0, truth, seed=1000, n_rows=100_000), FitOptions()
    else:
        pe = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0)
        table, opts = emulate_campaign(0, truth, seed=1000, n_rows=100_000, pose_error=pe), FitOptions(free=EIV_FREE)
    check = est.goodness_of_fit
    spent: list[tuple[float, float]] = []

    def timed(*args, **kw):
        t0, c0 = time.perf_counter(), time.process_time()
        out = check(*args, **kw)
        spent.append((time.perf_counter() - t0, time.process_time() - c0))
        return out

    times: dict[bool, list[tuple[float, float, float]]] = {True: [], False: []}
    for _ in range(rounds):
        for on in (False, True):
            est.goodness_of_fit = timed if on else (lambda *a, **k: None)
            load, t0, c0 = os.getloadavg()[0], time.perf_counter(), time.process_time()
            fit(table, opts)
            times[on].append((time.perf_counter() - t0, time.process_time() - c0, load))
    est.goodness_of_fit = check
    for on in (False, True):
        cells = " ".join(f"{w:.2f} s wall / {c:.2f} s CPU (load {ld:.1f})" for w, c, ld in times[on])
        print(f"{kind}, {'with the check' if on else 'without it'}: {cells}")
    print(f"{kind}, the check itself: " + " ".join(f"{w:.2f} s wall / {c:.2f} s CPU" for w, c in spent))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
