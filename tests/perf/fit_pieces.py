"""The pose-error rule's piece length (bench/fit/pose_error.py: SIGNAL_PIECE): accuracy and CPU.

Usage: python tests/perf/fit_pieces.py [--seed N]

The 1e5-row pose-error campaign of ``bench_fit.py --pose-error`` (seed 1000 + N), fitted
as shipped; then on a seeded 10,000-row subsample of the rows the fit used, at its
estimate, every row's log P with the piecewise rule of LINEARISING_PIECE (pieces of at
most 2 s.d., 6 Gauss-Legendre nodes each: the rule before SIGNAL_PIECE) and of
SIGNAL_PIECE (4 s.d., 8 nodes), against a reference of 12 nodes per 0.125 s.d.; and the
CPU time of one evaluation with each (best of 5). Prints one line per rule.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

from bench.fit import EIV_FREE, FitOptions, fit_table  # noqa: E402
from bench.fit.eiv import model_rows  # noqa: E402
from bench.fit.likelihood import Likelihood  # noqa: E402
from bench.fit.pose_error import LINEARISING_PIECE, SIGNAL_PIECE  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402
from fit_campaign import PoseError, emulate_campaign  # noqa: E402

TARGET = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0)


def logp_with(rows, params, piece: tuple[float, int], reps: int = 5):
    """(log P per row, CPU s of one evaluation, best of ``reps``) with the pose-error rule
    ``piece``: pieces of at most piece[0] s.d., piece[1] Gauss-Legendre nodes each."""
    like = Likelihood(replace(rows, moments=replace(rows.moments, piece=piece)))
    like.choose_regimes(params)
    best = float("inf")
    for i in range(reps):  # (distinct points: nothing is memoised)
        c0 = time.process_time()
        like.logp(replace(params, kappa_eq=params.kappa_eq * (1.0 + 1e-12 * (i + 1))))
        best = min(best, time.process_time() - c0)
    return like.logp(params), best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    table = emulate_campaign(0, ModelParams(kappa_eq=1.542, r_en=80.0), seed=1000 + args.seed, n_rows=100_000, pose_error=TARGET)
    res = fit_table(table, FitOptions(free=EIV_FREE))
    rows = model_rows(table, res.params)
    idx = np.sort(np.random.default_rng(0).choice(rows.k.shape[0], 10_000, replace=False))
    sub = rows.take(idx, track=False)
    ref, _ = logp_with(sub, res.params, (0.125, 12), reps=1)
    for name, piece in (("LINEARISING_PIECE", LINEARISING_PIECE), ("SIGNAL_PIECE", SIGNAL_PIECE)):
        lp, cpu = logp_with(sub, res.params, piece)
        d = lp - ref
        print(
            f"{name} = {piece[0]:g} s.d., {piece[1]} nodes: max |d log P| {np.max(np.abs(d)):.2e}, rms {np.sqrt(np.mean(d * d)):.1e}, "
            f"sum {np.sum(d):+.1e} nats; one evaluation {1e3 * cpu:.2f} ms CPU"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
