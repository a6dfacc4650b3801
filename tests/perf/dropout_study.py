"""Spurious "nothing heard" rows and the dropout probability (issue 28, Build item 3).

Usage: python tests/perf/dropout_study.py [--seeds 4] [--exact]

Each seeded 60-minute campaign (1 Hz radial walks; consumer GPS error 1 m / 1.5 m
Gauss-Markov 30 s and 2 deg attitude unless --exact) gets 2 % of its detected rows turned
into -1 rows; it is fitted as ``arva-bench fit`` does (sigmas estimated, no offset scan)
and again with ``dropout`` free. Prints r_en and kappa_eq against the truth (80 m, 1.48)
in standard errors, and the dropout estimate (2 % injected).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

from fit_campaign import PoseError, emulate_campaign  # noqa: E402

from bench.fit import EIV_FREE, FitOptions, fit  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402

TRUTH = ModelParams(kappa_eq=1.48, r_en=80.0)
GPS = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--exact", action="store_true", help="exact poses (kappa_eq, r_en, pose_sigma free)")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at start")
    print("seed  dropout free  converged  r_en     z(r_en)  z(kappa)  dropout")
    base_free = ("kappa_eq", "r_en", "pose_sigma") if args.exact else EIV_FREE
    r_en = {False: [], True: []}
    for seed in range(args.seeds):
        table = emulate_campaign(60, TRUTH, seed=seed, pose_error=PoseError() if args.exact else GPS)
        rng = np.random.default_rng(100 + seed)
        det = np.flatnonzero(table.d != -1)
        idx = rng.choice(det, int(0.02 * det.size), replace=False)
        table.d[idx], table.id[idx], table.delta[idx] = -1, -1, -1
        for with_dropout in (False, True):
            free = base_free + (("dropout",) if with_dropout else ())
            res = fit(table, FitOptions(free=free, scan_offset=False))
            z = (res.estimate["r_en"] - TRUTH.r_en) / res.se["r_en"]
            zk = (res.estimate["kappa_eq"] - TRUTH.kappa_eq) / res.se["kappa_eq"]
            r_en[with_dropout].append(res.estimate["r_en"])
            print(f"{seed:<5} {str(with_dropout):<13} {str(res.converged):<10} {res.estimate['r_en']:7.2f}  {z:+6.2f}  {zk:+7.2f}   {res.params.dropout:.4f}")
    for k, v in r_en.items():
        print(f"dropout free={k}: mean r_en error {100 * (np.mean(v) / TRUTH.r_en - 1):+.2f} %")
    print(f"load average {os.getloadavg()[0]:.2f} at end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
