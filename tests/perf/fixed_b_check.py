"""Coverage of the sandwich's time-block intervals on simulated score series: why
``bench/fit/covariance.py: fixed_b_scale`` scales the sandwich (docs/calibration.md,
section 5).

Each series is one parameter's per-second score sum over a log of T seconds: white
noise (the EMI part) plus ``mix`` times a unit Gauss-Markov process with time constant
``tau`` (the pose-error part). The interval is sum +- c sqrt(meat), the meat the
fit's own :func:`time_block_meat` at the bandwidth it chooses,
c = 1.96 and the fixed-b critical value c(b). An exact interval covers 95 %.

Usage: python tests/perf/fixed_b_check.py [--seconds 3600] [--series 6000] [--tau 30]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bench.fit.covariance import fixed_b_scale, time_block_meat  # noqa: E402
from emulator.cli_types import integer, positive_int, real  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=integer(16, 10**7), default=3600)
    ap.add_argument("--series", type=positive_int, default=6000)
    ap.add_argument("--tau", type=real(0.0, 1e6, lo_open=True), default=30.0,
                    help="the correlated part's time constant (s)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(2)
    t = np.arange(float(args.seconds))
    rho = math.exp(-1.0 / args.tau)
    print(f"T = {args.seconds} s, {args.series} series, tau = {args.tau:g} s")
    print("| correlated part (s.d.) | bandwidth (s) | b | c(b) | covered at 1.96 | covered at c(b) |")
    print("|---|---|---|---|---|---|")
    for mix in (0.0, 0.1, 0.3, 1.0):
        hits, lags = np.zeros(2), []
        for _ in range(args.series):
            white = rng.standard_normal(args.seconds)  # (drawn first: the docs' table is of this order)
            part = lfilter([1.0], [1.0, -rho], rng.standard_normal(args.seconds) * math.sqrt(1 - rho * rho))
            x = white + mix * part
            meat, lag = time_block_meat(x[:, None], t)
            z = abs(x.sum()) / math.sqrt(meat[0, 0])
            hits += [z < 1.96, z < 1.96 * math.sqrt(fixed_b_scale(lag, t))]
            lags.append(lag)
        lag = float(np.median(lags))  # (the bandwidth's floor 4 sqrt(T) in every row measured)
        c = 1.96 * math.sqrt(fixed_b_scale(lag, t))
        print(f"| {mix:g} | {lag:.0f} | {lag / args.seconds:.3f} | {c:.2f} | "
              f"{100 * hits[0] / args.series:.1f} % | {100 * hits[1] / args.series:.1f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
