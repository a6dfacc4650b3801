"""Could scipy's L-BFGS-B replace the fit's own Newton search? A measurement (issue 28).

Usage: python tests/perf/fit_lbfgsb.py [--minutes 155] [--seeds 3]

For each seeded campaign (1 Hz radial walks, consumer GPS error: 1 m / 1.5 m Gauss-Markov
30 s, 2 deg attitude; 155 minutes = 9,300 rows, the size the issue quotes) the default fit
(sigmas estimated) runs first. Then, on the rows and likelihood regimes of its last pass
(the same objective), from the same pilot start:

* ``newton``: the fit's search (:func:`bench.fit.search.newton`, Hessian by differences at
  each iteration) to its tolerance (a decrement of 1e-5 nats);
* ``lbfgsb-2pt``: ``scipy.optimize.minimize(method="L-BFGS-B")`` in the same box with
  scipy's forward-difference gradient;
* ``lbfgsb-3pt``: the same with central differences (steps of the fit's initial ones);
* ``lbfgsb-3pt-tight``: that with ftol 1e-13 and gtol 1e-7 (scipy's defaults stop early).

Printed per method: likelihood evaluations, wall time (with the load average), the
largest distance of its optimum from the Newton optimum in standard errors (the fit's,
on the optimiser's scale; parameters held at a floor have none and are left out) and the
difference in negative log-likelihood (nats).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

from scipy.optimize import minimize  # noqa: E402

from fit_campaign import PoseError, emulate_campaign  # noqa: E402

from bench.fit import EIV_FREE, FitOptions, fit  # noqa: E402
from bench.fit.eiv import eiv_rows, rule_sigmas  # noqa: E402
from bench.fit.likelihood import Likelihood, from_params, rows_from_table  # noqa: E402
from bench.fit.params import box, initial_steps  # noqa: E402
from bench.fit.pilot import median_kappa  # noqa: E402
from bench.fit.search import DECREMENT_TOL, Differences, Objective, newton  # noqa: E402
from bench.fit.table import gps_scale  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402

TRUTH = ModelParams(kappa_eq=1.48, r_en=80.0)
GPS = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0)


def one(minutes: float, seed: int) -> list[dict]:
    table = emulate_campaign(minutes, TRUTH, seed=seed, pose_error=GPS)
    res = fit(table, FitOptions(free=EIV_FREE, scan_offset=False))
    free = tuple(n for n in res.free if n != "r_outer")
    # the objective of the fit's last pass: rows linearised at its estimate, regimes there
    rows = rows_from_table(table)
    rows.gps_scale = gps_scale(table)
    rows, _ = eiv_rows(rows, table, rule_sigmas(res.params, free), attitude=res.params.attitude_sigma)
    like = Likelihood(rows)
    like.choose_regimes(res.params)
    base = res.params
    obj = Objective(like, base, free)
    # the same start for all: the pilot's kappa_eq, r_en 80 m, the sigmas' starting values
    start = from_params(base, free)
    start[free.index("kappa_eq")] = math.log(median_kappa(rows, base.r_inner))
    start[free.index("r_en")] = math.log(80.0)
    start[free.index("gps_sigma")] = math.log(0.5)
    start[free.index("attitude_sigma")] = math.log(math.radians(1.0))
    lo, hi = box(free)
    out = []

    def timed(name, run):
        n0 = like.n_evals
        t0 = time.perf_counter()
        theta = run()
        out.append({"method": name, "theta": theta, "evals": like.n_evals - n0, "wall": time.perf_counter() - t0})

    timed("newton", lambda: newton(Differences(obj), start, free, 60, DECREMENT_TOL, recompute=True).theta)
    timed("lbfgsb-2pt", lambda: minimize(obj, start, method="L-BFGS-B", bounds=list(zip(lo, hi))).x)
    h = initial_steps(free)

    def central(theta):
        g = np.empty(len(theta))
        for i in range(len(theta)):
            e = np.zeros(len(theta))
            e[i] = h[i]
            g[i] = (obj(np.clip(theta + e, lo, hi)) - obj(np.clip(theta - e, lo, hi))) / (2 * h[i])
        return g

    timed("lbfgsb-3pt", lambda: minimize(obj, start, jac=central, method="L-BFGS-B", bounds=list(zip(lo, hi))).x)
    tight = {"ftol": 1e-13, "gtol": 1e-7, "maxls": 40}
    timed("lbfgsb-3pt-tight", lambda: minimize(obj, start, jac=central, method="L-BFGS-B", bounds=list(zip(lo, hi)), options=tight).x)
    ref = out[0]["theta"]
    # standard errors on the optimiser's scale: the fit's covariance (its sandwich)
    se = np.sqrt(np.diag(res.cov_theta)[[res.free.index(n) for n in free]])
    has = np.isfinite(se) & (se > 0)
    for r in out:
        r["max_se"] = float(np.max(np.abs((r["theta"] - ref)[has] / se[has]))) if has.any() else float("nan")
        r["fit"] = f"fit converged={res.converged}" + ("" if res.converged else f" ({res.message})")
        r["dnll"] = obj(r["theta"]) - obj(ref)
        r["rows"] = like.k.shape[0]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=155.0)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at start")
    print("seed  rows   method             evals   wall s   |optimum - Newton's| (s.e.)   dNLL")
    for seed in range(args.seeds):
        rs = one(args.minutes, 2000 + seed)
        print(f"{2000 + seed:<5} {rs[0]['fit']}")
        for r in rs:
            print(f"{2000 + seed:<5} {r['rows']:<6} {r['method']:<18} {r['evals']:>5}  {r['wall']:7.2f}   {r['max_se']:10.4f}   {r['dnll']:+.2e}")
    print(f"load average {os.getloadavg()[0]:.2f} at end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
