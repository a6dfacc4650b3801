"""Refactoring guard for bench/fit: seeded fits over the fit's code paths, dumped to JSON,
and a comparison of two dumps in standard-error units.

Usage:
    python tests/perf/fit_baseline.py run OUT.json [--only NAME,...]
    python tests/perf/fit_baseline.py compare BEFORE.json AFTER.json

The cases (each one fit of an emulated campaign, ``tests/fit_campaign.py``):

* ``exact_grad``: exact poses, kappa_eq, r_en, pose_sigma (the analytic-gradient Newton);
* ``exact_grad_big``: the same on 12,000 rows (subsample search, then all rows);
* ``exact_q``: exact poses with q free (finite differences: q has no analytic gradient);
* ``exact_r_outer``: exact poses with r_outer free (its 1-D search, then a refit);
* ``eiv_default``: pose error, the command line's default (sigmas estimated, offset scan);
* ``eiv_big``: the same on a 190-minute campaign (> 10,000 rows kept: the subsample
  search, BFGS steps and the Hessian on all rows, the worker process);
* ``eiv_offset``: pose error with a 0.6 s clock offset (found by the scan, then fitted);
* ``eiv_given``: sigmas given, kappa_eq and r_en free;
* ``eiv_floor``: exact poses fitted with pose error free (sigmas at their floors: the
  nuisance-variance covariance);
* ``no_noise``: no EMI at all (r_en runs to its upper bound: not converged).

``compare`` prints, per case and parameter, the difference of the estimates in units of
the first dump's standard error, whether each number is bit-identical, and whether the
converged flags, messages, notes and evaluation counts agree; exit 1 if any estimate
moved by more than 0.01 s.e. or a flag, message or note differs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

from fit_campaign import PoseError, emulate_campaign  # noqa: E402

try:  # noqa: E402
    from bench.fit import EIV_FREE, FitOptions, fit_table
except ImportError:  # (a revision before bench.fit.fit was the function)
    from bench.fit.fit import EIV_FREE, FitOptions, fit_table
from bench.fit.likelihood import Params  # noqa: E402
from emulator.receiver.model import ModelParams, measure  # noqa: E402

TRUTH = ModelParams(kappa_eq=1.48, r_en=80.0)
GPS = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0)
EXACT = ("kappa_eq", "r_en", "pose_sigma")


def _no_noise():
    t = emulate_campaign(10, TRUTH, seed=1)
    t.d = measure(t.rx_pos, t.rx_quat, t.tx_pos[:1], t.tx_quat[:1], TRUTH).d[:, 0]
    return t, FitOptions(free=EIV_FREE)


CASES = {
    "exact_grad": lambda: (emulate_campaign(30, TRUTH, seed=11), FitOptions(free=EXACT)),
    "exact_grad_big": lambda: (emulate_campaign(0, TRUTH, seed=12, n_rows=12000), FitOptions(free=EXACT)),
    "exact_q": lambda: (
        emulate_campaign(30, ModelParams(kappa_eq=1.48, r_en=80.0, q=(1.0, 0.7, 1.0)), seed=13),
        FitOptions(free=("kappa_eq", "r_en", "q", "pose_sigma")),
    ),
    "exact_r_outer": lambda: (
        emulate_campaign(30, TRUTH, seed=14),
        FitOptions(free=("kappa_eq", "r_en", "r_outer", "pose_sigma")),
    ),
    "eiv_default": lambda: (emulate_campaign(60, TRUTH, seed=15, pose_error=GPS), FitOptions(free=EIV_FREE)),
    "eiv_big": lambda: (emulate_campaign(190, TRUTH, seed=16, pose_error=GPS), FitOptions(free=EIV_FREE)),
    "eiv_offset": lambda: (
        emulate_campaign(30, TRUTH, seed=17, pose_error=PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, time_offset=0.6)),
        FitOptions(free=EIV_FREE),
    ),
    "eiv_given": lambda: (
        emulate_campaign(60, TRUTH, seed=18, pose_error=GPS),
        FitOptions(free=("kappa_eq", "r_en"), base=Params(gps_sigma=1.0, gps_ratio=1.5, attitude_sigma=math.radians(2.0))),
    ),
    "eiv_floor": lambda: (emulate_campaign(30, TRUTH, seed=19), FitOptions(free=EIV_FREE)),
    "no_noise": _no_noise,
}


def run_case(name: str) -> dict:
    table, options = CASES[name]()
    t0 = time.perf_counter()
    res = fit_table(table, options)
    wall = time.perf_counter() - t0
    return {
        "n_rows": res.n_rows,
        "n_used": res.n_used,
        "free": list(res.free),
        "estimate": res.estimate,
        "se": res.se,
        "se_model": res.se_model,
        "log_likelihood": res.log_likelihood,
        "converged": res.converged,
        "message": res.message,
        "notes": res.notes,
        "iterations": res.iterations,
        "n_evals": res.n_evals,
        "n_evals_all_rows": res.n_evals_all_rows,
        "hac_lag": res.hac_lag,
        "params": {k: getattr(res.params, k) for k in ("kappa_eq", "r_en", "r_outer", "pose_sigma", "time_offset", "gps_sigma", "attitude_sigma")},
        "q": list(res.params.q),
        "wall_seconds": wall,
    }


def _num(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def _clean(obj):
    if isinstance(obj, float):
        return _num(obj)
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_clean(v) for v in obj]
    return obj


def compare(a: dict, b: dict) -> int:
    worst = 0.0
    bad = False
    for name in a:
        if name not in b:
            print(f"{name}: missing in the second dump")
            bad = True
            continue
        x, y = a[name], b[name]
        line = []
        for p, v in x["estimate"].items():
            w = y["estimate"].get(p)
            se = x["se"].get(p) or x["se_model"].get(p)
            if v is None or w is None:
                same = v == w
                line.append(f"{p} {'same' if same else 'DIFFERS'}")
                bad |= not same
                continue
            diff = abs(w - v) / se if se else (0.0 if v == w else math.inf)
            worst = max(worst, diff)
            line.append(f"{p} {'bit-identical' if v == w else f'{diff:.2g} se'}")
            if diff > 0.01:
                bad = True
        se_moves = [
            abs(y["se"][p] / x["se"][p] - 1) for p in x["se"] if x["se"][p] and y["se"].get(p)
        ]
        flags = {
            k: x[k] == y[k]
            for k in ("converged", "message", "notes", "iterations", "n_evals", "n_evals_all_rows", "log_likelihood", "se")
        }
        bad |= not (flags["converged"] and flags["message"] and flags["notes"])
        print(
            f"{name}: " + ", ".join(line)
            + f"; s.e. max rel change {max(se_moves, default=0.0):.2g}; "
            + " ".join(f"{k}={'=' if ok else 'DIFF'}" for k, ok in flags.items())
        )
    print(f"largest estimate difference: {worst:.3g} standard errors")
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out")
    r.add_argument("--only", default="")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "compare":
        return compare(json.loads(Path(args.a).read_text()), json.loads(Path(args.b).read_text()))
    names = [n for n in args.only.split(",") if n] or list(CASES)
    out = {}
    for name in names:
        out[name] = _clean(run_case(name))
        e = out[name]
        print(f"{name}: converged={e['converged']} evals={e['n_evals']} {e['wall_seconds']:.1f} s", flush=True)
    Path(args.out).write_text(json.dumps(out, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
