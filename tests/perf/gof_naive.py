"""Why the goodness-of-fit check needs time-block variances (docs/calibration.md, "Does the
model fit?"): the same PIT values tested three ways on well-specified campaigns of
``study_campaigns.py`` (tuning seeds, fitted in-process as ``arva-bench fit`` fits them):

* a plain Kolmogorov-Smirnov test of the PIT values at 5 % (rows taken as independent);
* the check's statistics with independent-rows variances (``pit_test`` with ``t=None``);
* the check as shipped (time-block variances with pose error).

Prints, per condition, how many converged fits each fires on.

Usage: python tests/perf/gof_naive.py [--seeds 8] [--conditions level-gm,radial-gm,radial-exact]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parents[1])]

from scipy.stats import kstest  # noqa: E402

import bench.fit.estimate as est  # noqa: E402
import study_campaigns as sc  # noqa: E402
from bench.fit import EIV_FREE, FitOptions, fit  # noqa: E402
from bench.fit import diagnostics as dg  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--conditions", default="level-gm,radial-gm,radial-exact")
    args = ap.parse_args(argv)
    kept: list[dg.PitRows] = []

    def keep(rows, p, seed=0):
        if rows.k.shape[0] < dg.MIN_BIN_ROWS:
            return None
        x = dg.pit_rows(rows, p, seed)
        kept.append(x)
        return dg.pit_test(x.u, x.r, x.t, x.censored, x.p_censored, center=x.gps_seen)

    est.goodness_of_fit = keep
    print("| condition | converged | KS 5 % | independent rows | time blocks (shipped) |")
    print("|---|---|---|---|---|")
    for name in args.conditions.split(","):
        counts = [0, 0, 0, 0]
        for seed in range(args.seeds):  # tuning seeds
            camp = sc.campaign(sc.CONDITIONS[name], seed)
            kept.clear()
            res = fit(parse_csv(camp.csv_text(), f"{name}-{seed}.csv"), FitOptions(free=EIV_FREE))
            if not res.converged or not kept:
                continue
            x = kept[-1]  # the fit that produced the result (after any time-offset refit)
            counts[0] += 1
            counts[1] += kstest(x.u, "uniform").pvalue < 0.05
            counts[2] += not dg.pit_test(x.u, x.r, None, x.censored, x.p_censored, center=x.gps_seen).fits
            counts[3] += not res.goodness_of_fit.fits
            print(f"  {name} seed {seed}: KS p {kstest(x.u, 'uniform').pvalue:.2g}, shipped p {res.goodness_of_fit.p_value:.2g}",
                  file=sys.stderr, flush=True)  # fmt: skip
        print(f"| {name} | {counts[0]} | {counts[1]} | {counts[2]} | {counts[3]} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
