"""Would a profile-likelihood interval for r_en cover better than the Wald interval
(estimate +- 1.96 s.e.) on the exact-pose walks? docs/calibration_study.md, "The profile
likelihood, measured".

For each tuning seed of an exact-pose condition of ``study_campaigns.py``: the fit of
(kappa_eq, r_en) with the relative pose error held at 1e-5 from the bound's estimate (as
``estimate.held_pose_sigma`` does), the likelihood-ratio statistic 2 (l_max - l_profile)
at the hidden truth of each parameter (the other refitted), and the standard errors from
the expected information (``FitOptions.expected_se``, 8 simulated outcome sets) beside
the observed. ``--our-model``: the campaign's outcomes replaced by a draw from the fit's
own model at the truth (the control). The interval covers when LR < 3.84 (chi-square(1)).

Usage: python tests/perf/profile_interval.py --condition far-exact [--seeds 0 50] [--our-model] --out F.jsonl
       python tests/perf/profile_interval.py --table F.jsonl [F.jsonl ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

import study_campaigns as sc  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.eiv import usable  # noqa: E402
from bench.fit.estimate import EXACT_POSE_SIGMA, check_table, fit, fit_restarted  # noqa: E402
from bench.fit.likelihood import simulate  # noqa: E402
from bench.fit.params import Params  # noqa: E402
from bench.fit.result import FitOptions  # noqa: E402
from emulator.cli_types import non_negative_int  # noqa: E402

NAMES = ("kappa_eq", "r_en")


def one(cond: sc.Condition, seed: int, ours: bool) -> dict | None:
    camp = sc.campaign(cond, seed)
    table = parse_csv(camp.csv_text().encode(), f"{cond.name}-{seed}.csv")
    t = camp.truth
    if ours:
        truth = Params(kappa_eq=t.kappa_eq, r_en=t.r_en, r_inner=t.r_inner, r_outer=t.r_outer, pose_sigma=0.0)
        rows = usable(check_table(table, FitOptions(free=NAMES, base=truth)))
        if rows.k.shape[0] != len(table):
            return None  # (a row at the transmitter was dropped: the draw would not line up)
        table.d[:] = simulate(rows.geo, truth, np.random.default_rng([seed, 77]))
    first = fit(table, FitOptions(free=NAMES + ("pose_sigma",)))
    base = Params(pose_sigma=EXACT_POSE_SIGMA)
    start = replace(first.params, pose_sigma=EXACT_POSE_SIGMA)
    full = fit_restarted(table, FitOptions(free=NAMES, base=base, start=start, expected_se=True))
    if not full.converged:
        return {"seed": seed, "converged": False}
    cov = np.linalg.inv(full.expected_information)
    rec = {"seed": seed, "converged": True, "truth": {n: getattr(t, n) for n in NAMES},
           "estimate": {n: full.estimate[n] for n in NAMES}, "se": {n: full.se[n] for n in NAMES},
           "se_expected": {n: float(np.sqrt(cov[i, i]) * full.estimate[n]) for i, n in enumerate(full.free)}}
    for name in NAMES:
        other = tuple(n for n in NAMES if n != name)
        at = replace(base, **{name: getattr(t, name)})
        start = replace(full.params, **{name: getattr(t, name)})
        prof = fit_restarted(table, FitOptions(free=other, base=at, start=start))
        rec[f"lr_{name}"] = 2.0 * (full.log_likelihood - prof.log_likelihood)
    return rec


def table(paths: list[str]) -> None:
    print("| runs | parameter | fits | Wald covers | Wald mean z | Wald RMS z | LR covers | signed-root RMS "
          "| expected-information covers |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in paths:
        recs = [r for r in map(json.loads, Path(path).read_text().splitlines()) if r.get("converged")]
        for n in NAMES:
            z = np.array([(r["estimate"][n] - r["truth"][n]) / r["se"][n] for r in recs])
            ze = np.array([(r["estimate"][n] - r["truth"][n]) / r["se_expected"][n] for r in recs])
            lr = np.array([r[f"lr_{n}"] for r in recs])
            root = np.sign(z) * np.sqrt(np.maximum(lr, 0.0))
            print(f"| {Path(path).stem} | {n} | {len(recs)} | {np.mean(abs(z) < 1.96):.0%} | "
                  f"{z.mean():+.2f} | {np.sqrt(np.mean(z * z)):.2f} | {np.mean(lr < 3.841):.0%} | "
                  f"{np.sqrt(np.mean(root**2)):.2f} | "
                  f"{np.mean(abs(ze) < 1.96):.0%} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    exact = sorted(n for n in sc.CONDITIONS if n.endswith("-exact"))
    ap.add_argument("--condition", choices=exact, default="far-exact")
    ap.add_argument("--seeds", type=non_negative_int, nargs=2, default=(0, 50), metavar=("FIRST", "END"),
                    help="tuning seeds [FIRST, END)")
    ap.add_argument("--our-model", action="store_true",
                    help="outcomes drawn from the fit's model at the truth (control)")
    ap.add_argument("--out", help="append one JSON line per seed here")
    ap.add_argument("--table", nargs="+", metavar="JSONL", help="print the table of these runs; fit nothing")
    args = ap.parse_args(argv)
    if args.table:
        table(args.table)
        return 0
    if not args.out:
        ap.error("--out is required to fit")
    with open(args.out, "a") as out:
        for seed in range(*args.seeds):
            rec = one(sc.CONDITIONS[args.condition], seed, args.our_model)
            if rec is not None:
                out.write(json.dumps(rec) + "\n")
                out.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
