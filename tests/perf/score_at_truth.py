"""Is the fit's likelihood the study generator's? The score at the hidden truth (issue 28).

For exact-pose campaigns of the calibration study (``study_campaigns.py``, tuning seeds from
0), the per-row score of the fit's likelihood (``bench.fit.likelihood.Likelihood``, the
relative pose error held at ``--pose-sigma``, by default 1e-5 as
``estimate.EXACT_POSE_SIGMA``) at the campaign's truth,
by central differences in log kappa_eq and log r_en. Where the model is the generator's,
the score's sum has mean 0, and z = sum / sqrt(sum of squares) is about N(0, 1) over
seeds. Prints one row per seed and a summary per parameter: mean and s.d. of z, and how
many |z| are above 2 and 3 (a normal z gives 4.6 % and 0.27 %). ``--our-model``: the
control, the same statistic on outcomes drawn from the fit's own model
(``likelihood.simulate``) for each campaign's geometry, so what is the statistic's own
finite-sample shape shows there too. ``--draws N`` (with ``--our-model``): N draws per
seed, and the raw r_en score sum's mean over them in its standard errors (0 where the
likelihood is the model's) beside the mean z. About 1 s per seed and draw.

Usage: python tests/perf/score_at_truth.py [--condition far-exact] [--seeds N] [--our-model]
"""

from __future__ import annotations

import argparse
import statistics
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
from bench.fit.estimate import EXACT_POSE_SIGMA, check_table  # noqa: E402
from bench.fit.likelihood import Likelihood, from_params, simulate, to_params  # noqa: E402
from bench.fit.params import Params  # noqa: E402
from bench.fit.result import FitOptions  # noqa: E402

FREE = ("kappa_eq", "r_en")
STEP = 1e-4  # in the optimiser's log scale


def scores(cond: sc.Condition, seed: int, pose_sigma: float, ours: bool = False, draw: int = 0):
    """(rows, heard rows, the per-row score (rows, 2) in log kappa_eq and log r_en at the
    truth, the relative pose error held at ``pose_sigma``); ``ours``: the outcomes drawn
    from the fit's model at the truth instead of the generator's (``draw``: which draw)."""
    camp = sc.campaign(cond, seed)
    table = parse_csv(camp.csv_text(), f"{cond.name}-{seed}")
    t = camp.truth
    truth = Params(kappa_eq=t.kappa_eq, r_en=t.r_en, r_inner=t.r_inner, r_outer=t.r_outer,
                   pose_sigma=pose_sigma)
    rows = usable(check_table(table, FitOptions(free=FREE, base=truth)))
    if ours:
        drawn = simulate(rows.geo, replace(truth, pose_sigma=0.0), np.random.default_rng([seed, draw]))
        rows = replace(rows, k=drawn)
    like = Likelihood(rows)
    like.choose_regimes(truth)
    theta = from_params(truth, FREE)
    out = np.zeros((rows.k.shape[0], len(FREE)))
    for j in range(len(FREE)):
        up, down = theta.copy(), theta.copy()
        up[j] += STEP
        down[j] -= STEP
        diff = like.logp(to_params(truth, FREE, up)) - like.logp(to_params(truth, FREE, down))
        out[:, j] = diff / (2 * STEP)
    return rows.k.shape[0], int(np.sum(rows.k >= 0)), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    exact = [n for n in sc.CONDITIONS if n.endswith("-exact")]
    ap.add_argument("--condition", default="far-exact", choices=exact)
    ap.add_argument("--seeds", type=int, default=50, help="tuning seeds from 0")
    ap.add_argument("--pose-sigma", type=float, default=EXACT_POSE_SIGMA, help="the relative pose error held")
    ap.add_argument("--our-model", action="store_true", help="outcomes from the fit's model (the control)")
    ap.add_argument("--draws", type=int, default=0, help="with --our-model: N draws per seed (raw sums)")
    args = ap.parse_args(argv)
    if args.draws:
        for seed in range(args.seeds):
            cond = sc.CONDITIONS[args.condition]
            runs = [scores(cond, seed, args.pose_sigma, True, k)[2] for k in range(args.draws)]
            sums = np.array([s[:, 1].sum() for s in runs])
            z = np.mean([s[:, 1].sum() / np.sqrt((s[:, 1] ** 2).sum()) for s in runs])
            mean_se = sums.mean() / (sums.std(ddof=1) / np.sqrt(len(sums)))
            print(f"seed {seed}: r_en raw score sum mean / se {mean_se:+.2f}; mean z {z:+.2f}", flush=True)
        return 0
    cond = sc.CONDITIONS[args.condition]
    zs: list[np.ndarray] = []
    print("| seed | rows | heard | z kappa_eq | z r_en |")
    print("|---|---|---|---|---|")
    for seed in range(args.seeds):
        n, heard, s = scores(cond, seed, args.pose_sigma, args.our_model)
        z = s.sum(axis=0) / np.sqrt((s * s).sum(axis=0))
        zs.append(z)
        print(f"| {seed} | {n} | {heard} | {z[0]:+.2f} | {z[1]:+.2f} |", flush=True)
    print()
    source = "the fit's own model (control)" if args.our_model else "the generator"
    head = f"{args.condition}, seeds 0-{args.seeds - 1}, pose_sigma {args.pose_sigma:g}"
    print(f"{head}, outcomes from {source}:")
    for j, name in enumerate(FREE):
        col = [float(z[j]) for z in zs]
        print(
            f"  {name}: z mean {statistics.fmean(col):+.2f}, s.d. {statistics.stdev(col):.2f}, "
            f"|z| > 2: {sum(abs(v) > 2 for v in col)}, |z| > 3: {sum(abs(v) > 3 for v in col)} of {len(col)}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
