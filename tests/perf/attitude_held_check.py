"""Does the attitude error's floor pull r_en? One campaign of the calibration study
(``study_campaigns.py``) fitted with the command line's defaults, then with the attitude
error held at given values (kappa_eq, r_en and gps_sigma free, no time-offset scan):
each fit's r_en, its z against the hidden truth, the log-likelihood against the
default fit's and the rows each used (a pose-error fit leaves out rows that the pose
error hides, so likelihoods of fits that use different rows do not compare).
docs/calibration_study.md, "Measured: the fixed-b scale of the sandwich".

Usage: python tests/perf/attitude_held_check.py [--condition drone-gm] [--seed 1000007] [--deg 0.5 1 2]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

import study_campaigns as sc  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.estimate import fit  # noqa: E402
from bench.fit.params import Params  # noqa: E402
from bench.fit.result import EIV_FREE, FitOptions  # noqa: E402
from emulator.cli_types import real, seed  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--condition", default="drone-gm", choices=sorted(sc.CONDITIONS))
    ap.add_argument("--seed", type=seed, default=1_000_007)
    ap.add_argument("--deg", type=real(0.0, 90.0, lo_open=True), nargs="+", default=[0.5, 1.0, 2.0],
                    help="attitude errors to hold (deg)")
    args = ap.parse_args(argv)
    camp = sc.campaign(sc.CONDITIONS[args.condition], args.seed)
    table = parse_csv(camp.csv_text().encode(), f"{args.condition}-{args.seed}.csv")
    truth = camp.truth.r_en
    print(f"{args.condition} seed {args.seed}: truth r_en {truth:.2f} m")
    print("| attitude error | r_en (m) | r_en z | log-likelihood - the default's | rows used |")
    print("|---|---|---|---|---|")
    default = fit(table, FitOptions(free=EIV_FREE))
    fits = [(f"fitted: {math.degrees(default.params.attitude_sigma):.2f} deg", default)]
    for deg in args.deg:
        base = Params(attitude_sigma=math.radians(deg))
        held = FitOptions(free=("kappa_eq", "r_en", "gps_sigma"), base=base, scan_offset=False)
        fits.append((f"held at {deg:g} deg", fit(table, held)))
    for label, res in fits:
        z = (res.estimate["r_en"] - truth) / res.se["r_en"]
        gain = res.log_likelihood - default.log_likelihood
        print(f"| {label} | {res.estimate['r_en']:.2f} | {z:+.2f} | {gain:+.2f} | {res.n_used} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
