"""Why kappa_eq intervals under pose error cover what they cover (issue 15): cheap checks.

Usage: python tests/perf/pose_error_diagnosis.py MINUTES GPS_H SEEDS {known,free} VARIANTS
           [--errors gm|white|gpsonly|attonly|gpswhite|hwhite|attwhite] [--workers 2] [--out FILE]
   e.g. python tests/perf/pose_error_diagnosis.py 30 1.0 24 known plain,nocommon_v
        python tests/perf/pose_error_diagnosis.py 240 1.0 50 known plain,iidmeat,maxsd=0.05 --errors white --workers 1

``--errors`` picks the pose error drawn (:data:`ERRORS`; ``known`` fits give the fit the
sigmas of exactly that error). Besides the variants below, :func:`_patch` lists the
switches of single fit stages (maxsd=X, iidmeat, lagfrac=F, notweedie, noshrink) and
``fixwalk=W`` (one walk, many pose-error draws); parts combine with ``+``.

Campaigns as in accuracy_pose_error.py (seeds 9000 + s, Gauss-Markov GPS error GPS_H /
1.5 GPS_H, tau 30 s, 2 deg attitude error), fitted with the sigmas given (``known``) or
estimated (``free``). Variants: ``plain``; ``nocommon_v``, the logged heights minus the
campaign mean of their vertical error (the common height error removed, all else equal);
``nocommon_all``, the mean of all three error components removed. Each fit is appended
to tests/perf/out/pose_error_diagnosis.jsonl with the realised mean GPS error; the
summary per (minutes, grade, sigmas, variant) gives bias, RMS error, median s.e., the RMS
of error / s.e. and the coverage of +-1.96 s.e., and for ``nocommon_v`` how far removing
the common height error moved kappa_eq.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from accuracy_pose_error import one_process_per_fit  # noqa: E402

OUT = HERE / "out" / "pose_error_diagnosis.jsonl"
TRUTH = {"kappa_eq": 1.542, "r_en": 80.0}


ERRORS = {  # error model name -> PoseError keywords for GPS_H = h
    "gm": lambda h: dict(gps_h=h, gps_v=1.5 * h, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0),
    "white": lambda h: dict(gps_h=h, gps_v=1.5 * h, attitude_deg=2.0),
    "gpsonly": lambda h: dict(gps_h=h, gps_v=1.5 * h, gps_tau=30.0),
    "attonly": lambda h: dict(attitude_deg=2.0, attitude_tau=30.0),
    "gpswhite": lambda h: dict(gps_h=h, gps_v=1.5 * h),
    "hwhite": lambda h: dict(gps_h=h, gps_v=0.01 * h),  # (gps_ratio 0 divides by zero in fit_table)
    "attwhite": lambda h: dict(attitude_deg=2.0),
}
_ORIGINAL = {}


def _patch(variant: str) -> None:
    """Switch one stage of the fit for a variant (this process only; the shipped code is
    unchanged): ``maxsd=X`` keeps rows with pose-error spread <= X (pose_error.MAX_SD is
    0.15); ``iidmeat``: the sandwich meat from per-second score sums without the
    Newey-West lags (right for white pose error); ``lagfrac=F``: Newey-West (Bartlett)
    with the bandwidth F T, T the seconds logged; ``notweedie``: no horizontal Tweedie
    shift (the vertical shrinkage stays); ``noshrink``: no vertical shrinkage; ``fixwalk=W``
    (in :func:`one`): the walk and EMI of seed W for every seed, only the pose error drawn
    from the seed (the spread given the walk, and each walk's own bias). Parts join with +."""
    from bench.fit import covariance, eiv, estimate

    # each name in every module of bench/fit that uses it
    homes = {"MAX_SD": (eiv,), "time_block_meat": (estimate, covariance), "posterior_positions": (eiv, covariance)}

    def put(name, value):
        for module in homes[name]:
            setattr(module, name, value)

    for name in homes:
        _ORIGINAL.setdefault(name, getattr(homes[name][0], name))
        put(name, _ORIGINAL[name])
    for part in variant.split("+"):
        if part.startswith("maxsd="):
            put("MAX_SD", float(part.split("=")[1]))
        elif part == "iidmeat":

            def iid(scores, t):
                sec = np.floor(t - t.min()).astype(np.int64)
                x = np.stack([np.bincount(sec, weights=scores[:, j]) for j in range(scores.shape[1])], axis=1)
                x -= x.mean(axis=0)
                return x.T @ x, 0.0

            put("time_block_meat", iid)
        elif part.startswith("lagfrac="):  # Newey-West bandwidth L = F T instead of the plug-in
            frac = float(part.split("=")[1])

            def fixed_lag(scores, t, frac=frac):
                sec = np.floor(t - t.min()).astype(np.int64)
                x = np.stack([np.bincount(sec, weights=scores[:, j]) for j in range(scores.shape[1])], axis=1)
                x -= x.mean(axis=0)
                big_l = int(frac * x.shape[0])
                cs = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(np.concatenate([x, np.zeros((big_l, x.shape[1]))]), axis=0)])
                windows = cs[1:] - np.concatenate([np.zeros((big_l, x.shape[1])), cs[: x.shape[0]]])
                return windows.T @ windows / (big_l + 1.0), float(big_l)

            put("time_block_meat", fixed_lag)
        elif part == "notweedie":
            put("posterior_positions", lambda rx, tx, sh, sv: _ORIGINAL["posterior_positions"](rx, tx, 0.0, sv))
        elif part == "noshrink":
            put("posterior_positions", lambda rx, tx, sh, sv: _ORIGINAL["posterior_positions"](rx, tx, sh, 0.0))


def one(minutes: float, h: float, seed: int, known: bool, variant: str, errors: str = "gm") -> dict:
    from fit_campaign import PoseError, emulate_campaign

    from bench.fit import FitOptions, fit_table
    from bench.fit.likelihood import Params
    from emulator.receiver.model import ModelParams

    _patch(variant)
    pe = PoseError(**ERRORS[errors](h))
    walk_seed, error_seed = 9000 + seed, None
    for part in variant.split("+"):
        if part.startswith("fixwalk="):  # one walk (and EMI) for every seed: only the pose error varies
            walk_seed, error_seed = 9000 + int(part.split("=")[1]), 100000 + seed
    table = emulate_campaign(minutes, ModelParams(**TRUTH), seed=walk_seed, pose_error=pe, error_seed=error_seed)
    true = emulate_campaign(minutes, ModelParams(**TRUTH), seed=walk_seed)
    mean = (table.rx_pos - true.rx_pos).mean(axis=0)
    if variant == "nocommon_v":
        table.rx_pos = table.rx_pos - np.array([0.0, 0.0, mean[2]])
    elif variant == "nocommon_all":
        table.rx_pos = table.rx_pos - mean
    if known:
        # the sigmas of the error drawn (none where the error model has none)
        ratio = pe.gps_v / pe.gps_h if pe.gps_h > 0 else 1.5
        base = Params(gps_sigma=pe.gps_h, gps_ratio=ratio, attitude_sigma=math.radians(pe.attitude_deg))
        opts = FitOptions(free=("kappa_eq", "r_en"), base=base)
    else:
        opts = FitOptions(free=("kappa_eq", "r_en", "gps_sigma", "attitude_sigma"))
    c0 = time.process_time()
    res = fit_table(table, opts)
    out = {"minutes": minutes, "h": h, "seed": seed, "known": known, "variant": variant, "errors": errors, "conv": res.converged,
           "cpu": time.process_time() - c0, "mean_err": mean.tolist(), "lag": res.hac_lag,
           "floor": [n.split(" ")[0] for n in res.notes if "at its lower bound" in n]}  # fmt: skip
    for k in ("gps_sigma", "attitude_sigma", *TRUTH):
        out[k] = res.estimate.get(k)
        out[k + "_se"] = res.se.get(k)
        out[k + "_sem"] = res.se_model.get(k)
    return out


def summary(rows: list[dict]) -> str:
    lines = []
    def key_of(r):
        return (r["minutes"], r["h"], r["known"], r.get("errors", "gm"), r["variant"])

    keys = sorted({key_of(r) for r in rows})
    for key in keys:
        rs = [r for r in rows if key_of(r) == key and r["conv"] and r["kappa_eq_se"]]
        if not rs:
            continue
        text = (f"{key[0]:g} min, GPS {key[1]:g} m, {key[3]} error, sigmas {'given' if key[2] else 'estimated'}, "
                f"{key[4]}: {len(rs)} seeds")  # fmt: skip
        for k in TRUTH:
            e = np.array([r[k] / TRUTH[k] - 1 for r in rs])
            se = np.array([r[k + "_se"] / TRUTH[k] for r in rs])
            z = e / se
            text += (f" | {k}: bias {100 * e.mean():+.2f} %, RMS {100 * np.sqrt(np.mean(e**2)):.2f} %, median se "
                     f"{100 * np.median(se):.2f} %, RMS z {np.sqrt(np.mean(z**2)):.2f}, bias z {z.mean():+.2f}, s.d. z {z.std():.2f}, covers {100 * np.mean(abs(z) <= 1.96):.0f} %")  # fmt: skip
        lines.append(text)
    plain = {(r["minutes"], r["h"], r["known"], r["seed"]): r for r in rows if r["variant"] == "plain" and r["conv"]}
    moved = [(r["kappa_eq"] / plain[k]["kappa_eq"] - 1, plain[k]["mean_err"][2], plain[k]["kappa_eq_se"] / plain[k]["kappa_eq"])
             for r in rows if r["variant"] == "nocommon_v" and r["conv"]
             for k in [(r["minutes"], r["h"], r["known"], r["seed"])] if k in plain]  # fmt: skip
    if moved:
        d, zb, se = (np.array(v) for v in zip(*moved))
        lines.append(
            f"common height error: removing it moved kappa_eq by RMS {100 * np.sqrt(np.mean(d**2)):.2f} % (max "
            f"{100 * np.abs(d).max():.2f} %) = {np.sqrt(np.mean(d**2)) / np.median(se):.2f} s.e.; campaign-mean vertical "
            f"error RMS {np.sqrt(np.mean(zb**2)):.3f} m; slope {100 * np.polyfit(zb, d, 1)[0]:.2f} % per m ({len(d)} seeds)"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("minutes", type=float)
    p.add_argument("gps_h", type=float)
    p.add_argument("seeds", type=int)
    p.add_argument("sigmas", choices=("known", "free"))
    p.add_argument("variants")
    p.add_argument("--first", type=int, default=0, help="the first seed (seeds FIRST .. FIRST + SEEDS - 1; default 0)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--errors", choices=sorted(ERRORS), default="gm", help="the pose error model (default gm: the issue's)")
    p.add_argument("--summary-only", action="store_true")
    p.add_argument("--out", type=Path, default=OUT, help="the JSON-lines file to append to and summarise (one per code revision)")
    a = p.parse_args(argv)
    out = a.out
    if not a.summary_only:
        out.parent.mkdir(exist_ok=True)
        jobs = [(a.minutes, a.gps_h, s, a.sigmas == "known", v, a.errors) for s in range(a.first, a.first + a.seeds) for v in a.variants.split(",")]
        with ProcessPoolExecutor(a.workers, initializer=one_process_per_fit) as pool, out.open("a") as f:
            for row in pool.map(one, *zip(*jobs)):
                f.write(json.dumps(row) + "\n")
                f.flush()
    rows = [json.loads(line) for line in out.read_text().splitlines() if line.strip()] if out.exists() else []
    print(summary(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
