"""What the default time-offset scan sees (issue 15): the gain of its best offset on 0.

Usage: python tests/perf/offset_scan_study.py [--workers 2]

Emulated campaigns (tests/fit_campaign.py; 1 m / 1.5 m Gauss-Markov GPS error, tau 30 s,
2 deg attitude error) whose poses are logged late by 0, 0.25, 0.5 or 1 s, fitted with the
default errors-in-variables model without the scan; then ``bench.fit.offset.offset_scan`` at
the estimate. Prints every run (JSON) and, per (minutes, offset), the range of the gains
(nats on the rows scanned) and how many exceed ``OFFSET_GAIN``: the numbers behind the
threshold in docs/calibration.md section 2, "Time offset".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

JOBS = (
    [(10, o, s) for s in range(6) for o in (0.0, 0.5)]
    + [(60, o, s) for s in range(8) for o in (0.0, 0.25, 0.5, 1.0)]
    + [(240, o, s) for s in range(6) for o in (0.0, 0.5)]
)


def one(job) -> dict:
    minutes, offset, seed = job
    from fit_campaign import PoseError, emulate_campaign

    from bench.fit import EIV_FREE, FitOptions, fit_table
    from bench.fit.offset import offset_scan
    from emulator.receiver.model import ModelParams

    pe = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0, time_offset=offset)
    table = emulate_campaign(minutes, ModelParams(kappa_eq=1.542, r_en=80.0), seed=seed, pose_error=pe)
    options = FitOptions(free=EIV_FREE, scan_offset=False)
    res = fit_table(table, options)
    c0 = time.process_time()
    scan = offset_scan(table, res.params, options)
    return {"minutes": minutes, "offset": offset, "seed": seed, "best": scan.offset, "gain": scan.gain,
            "rows": scan.rows, "cpu": time.process_time() - c0, "kappa_eq": res.estimate["kappa_eq"]}  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    from bench.fit.offset import OFFSET_GAIN

    gains = defaultdict(list)
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(one, JOBS):
            print(json.dumps(row), flush=True)
            gains[(row["minutes"], row["offset"])].append(row["gain"])
    print(f"\n| minutes | offset (s) | seeds | gain of the best offset (nats) | above {OFFSET_GAIN:g} |")
    print("|---|---|---|---|---|")
    for (minutes, offset), g in sorted(gains.items()):
        print(f"| {minutes} | {offset:g} | {len(g)} | {min(g):.1f}-{max(g):.1f} | {sum(x > OFFSET_GAIN for x in g)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
