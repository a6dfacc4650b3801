"""Why ``bench/fit/estimate.py: held_pose_sigma`` searches from the bound's estimate: the
profile of the exact-pose likelihood in r_en (kappa_eq refitted at each r_en) at pose_sigma
1e-4 (its bound) and at 1e-5, for one campaign of the calibration study
(``study_campaigns.py``), with the fit of (kappa_eq, r_en) from the pilot at each. At 1e-5
the profile is rough: on level-exact seed 1,000,009 the search from the pilot stops at an
r_en whose log-likelihood is ~21 nats below the profile's best near the truth.

Usage: python tests/perf/exact_pose_profile.py [--condition level-exact] [--seed 1000009]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

import study_campaigns as sc  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.estimate import fit  # noqa: E402
from bench.fit.params import Params  # noqa: E402
from bench.fit.result import FitOptions  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--condition", default="level-exact", choices=sorted(sc.CONDITIONS))
    ap.add_argument("--seed", type=int, default=1_000_009)
    args = ap.parse_args()
    camp = sc.campaign(sc.CONDITIONS[args.condition], args.seed)
    table = parse_csv(camp.csv_text().encode(), f"{args.condition}-{args.seed}.csv")
    print(f"{args.condition} seed {args.seed}: truth r_en {camp.truth.r_en:.3f} m")
    for pose_sigma in (1e-4, 1e-5):
        full = fit(table, FitOptions(free=("kappa_eq", "r_en"), base=Params(pose_sigma=pose_sigma)))
        print(f"pose_sigma {pose_sigma:g}: from the pilot r_en {full.estimate['r_en']:.3f} +- {full.se['r_en']:.3f}, "
              f"log-likelihood {full.log_likelihood:.1f}; profile (r_en, log-likelihood - the pilot's fit's):")
        for r_en in np.linspace(camp.truth.r_en - 0.6, camp.truth.r_en + 1.4, 11):
            prof = fit(table, FitOptions(free=("kappa_eq",), base=Params(pose_sigma=pose_sigma, r_en=float(r_en))))
            print(f"  {r_en:8.3f}  {prof.log_likelihood - full.log_likelihood:+8.2f}")


if __name__ == "__main__":
    main()
