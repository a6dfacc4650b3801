"""Issue 15 diagnosis: is the r_en / kappa_eq bias under GPS error in the moments or in the model's form?

Usage: python tests/perf/pose_error_oracle.py MINUTES FIRST_SEED END_SEED MODES OUT.jsonl
       (env SH = horizontal GPS sigma, default 1; OFF = seed offset, default 9000)

Campaigns of tests/fit_campaign.py with white horizontal GPS error (vertical 1 cm), fitted
with the sigmas given. Modes: ``plain`` (the shipped fit); ``omean`` / ``ovar`` / ``ofull``:
each row's expected true position, and (ovar/ofull) the variance and (ofull) the mean of
a_xy, a_3, replaced by the exact posterior given the logged position with the true walk
(sampled every 0.2 s) as the prior; ``exact`` / ``exacteiv``: the campaign without pose
error (note: ``exact`` holds pose_sigma at the library default 0.1 %, not fitted, so it is
biased by construction); suffixes ``_sg`` (outcomes simulated from the model's Gaussian
stand-in with the oracle moments), ``_sp`` (simulated at a posterior draw of the true
position: the real thing), ``_sm`` (the pose part from a posterior draw, the EMI at the
posterior mean). Rows go to OUT (JSON lines); summarise with the fields kappa_eq, r_en
and their _se against 1.542 and 80. Scratch tool, ~10 s per 4-hour seed and mode.
"""
import argparse
import sys, json, math, time
import os
from pathlib import Path
sys.path[:0] = [str(Path(__file__).resolve().parents[2]), str(Path(__file__).resolve().parents[1])]  # the repository, tests/
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
import bench.fit.estimate as fitmod  # (fit_table, FitOptions; its eiv_rows is patched below)
from bench.fit.pose_error import MAX_SD
from bench.fit.likelihood import geometry, Params
from bench.fit.pose_error import PoseMoments, pose_moments


def _a(diff, m, rr):
    """a_xy, a_3 (log r - log |g_xy| / 3, log r - log |g| / 3) for offsets diff (3, N),
    transmitter axes m (3, N) and receiver rotations rr (3, 3, N), as geometry() computes g."""
    r = np.sqrt(np.einsum("in,in->n", diff, diff))
    n = diff / np.where(r > 0, r, 1.0)
    uw = 3.0 * np.einsum("in,in->n", m, n) * n - m
    g = np.einsum("ijn,in->jn", rr, uw)
    with np.errstate(divide="ignore"):
        return np.log(r) - np.log(np.hypot(g[0], g[1])) / 3.0, np.log(r) - 0.5 * np.log(np.einsum("in,in->n", g, g)) / 3.0
from emulator.frames.rotation import rotation_components, unit_quaternion_components, x_axis_components
from fit_campaign import PoseError, emulate_campaign, walk_poses, Walk
from emulator.receiver.model import ModelParams
TRUTH = {"kappa_eq": 1.542, "r_en": 80.0}
ORIG = fitmod.eiv_rows

def fine_walk(seed, n, step=0.2):
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
    rng.uniform(0, 360); rng.normal(0, 30); rng.normal(0, 30)
    tf = np.arange(0, n, step)
    pos, _ = walk_poses(tf, Walk(), rng)
    return pos

def oracle(table, fine, sh):
    """posterior mean position and E/Var of a (both zones) per row, prior = fine true walk (uniform in time)."""
    tree = cKDTree(fine[:, :2])
    y = table.rx_pos
    n = y.shape[0]
    rr = rotation_components(unit_quaternion_components(table.rx_quat, "rx_q"))
    m = x_axis_components(unit_quaternion_components(table.tx_quat, "tx_q"))
    tx = table.tx_pos
    rng = np.random.default_rng(123); samp = np.empty((n, 3)); mean = np.empty((n, 3)); Ea = np.empty((2, n)); Va = np.empty((2, n))
    nb = tree.query_ball_point(y[:, :2], 4.5 * sh)
    for i in range(n):
        j = np.asarray(nb[i])
        if j.size == 0:
            j = np.array([tree.query(y[i, :2])[1]])
        d2 = np.sum((fine[j, :2] - y[i, :2]) ** 2, axis=1)
        w = np.exp(-0.5 * (d2 - d2.min()) / sh**2); w /= w.sum()
        x = fine[j]
        mean[i] = w @ x
        samp[i] = x[rng.choice(j.size, p=w)]
        diff = (x - tx[i]).T
        k = j.size
        ax, a3 = _a(diff, np.repeat(m[:, i:i+1], k, 1), np.repeat(rr[:, :, i:i+1], k, 2))
        for z, av in enumerate((ax, a3)):
            mu = w @ av; Ea[z, i] = mu; Va[z, i] = max(w @ (av - mu) ** 2, 0.0)
    STATE['samp'] = samp
    return mean, Ea, Va

STATE = {}
def patched(rows, table, sigma0):
    mode = STATE["mode"]
    mean, Ea, Va = STATE["oracle"]
    if not mode.startswith("o"):
        return ORIG(rows, table, sigma0)
    pos = mean.copy()
    rows.geo = geometry(pos, table.rx_quat, table.tx_pos, table.tx_quat)
    if mode == "omean":  # oracle mean, the rule's variance (prior sigma) around it
        mom = pose_moments(pos, table.rx_quat, table.tx_pos, table.tx_quat, tuple(sigma0))
    else:
        n = pos.shape[0]
        diff = (pos - table.tx_pos).T
        rr = rotation_components(unit_quaternion_components(table.rx_quat, "rx_q"))
        m = x_axis_components(unit_quaternion_components(table.tx_quat, "tx_q"))
        a0 = _a(diff, m, rr)
        z = [np.zeros((3, n)) for _ in range(4)]
        s2 = sigma0[0] ** 2
        if mode == "ofull":
            z[0][0] = (Ea[0] - a0[0]) / s2; z[1][0] = Va[0] / s2; z[2][0] = (Ea[1] - a0[1]) / s2; z[3][0] = Va[1] / s2
        elif mode == "ovar":  # oracle variance, no shift of the mean beyond the mean position
            z[1][0] = Va[0] / s2; z[3][0] = Va[1] / s2
        for arr in z:
            arr[~np.isfinite(arr)] = 0.0
        mom = PoseMoments(z[0], z[1], z[2], z[3], tuple(sigma0), np.zeros(n), np.zeros(n))
    rows.moments = mom
    _m, vxy, _m3, v3 = mom.spread(np.asarray(sigma0))
    finite = np.isfinite(rows.geo.log_r)
    keep = finite & (np.maximum(vxy, v3) <= MAX_SD ** 2)
    return rows.take(keep), int(np.sum(finite & ~keep))
fitmod.eiv_rows = patched
import bench.fit.offset  # noqa: E402 (the offset scan builds its rows too)
bench.fit.offset.eiv_rows = patched

def run(minutes, seed, modes, out):
    pe = PoseError(gps_h=SH, gps_v=0.01)
    table = emulate_campaign(minutes, ModelParams(**TRUTH), seed=OFF + seed, pose_error=pe)
    exact = emulate_campaign(minutes, ModelParams(**TRUTH), seed=OFF + seed)
    fine = fine_walk(OFF + seed, table.t.shape[0])
    t0 = time.process_time()
    STATE["oracle"] = oracle(table, fine, SH) if any(m.startswith("o") for m in modes) else (None, None, None)
    to = time.process_time() - t0
    base = Params(gps_sigma=SH, gps_ratio=0.01, attitude_sigma=0.0)
    for mode in modes:
        STATE["mode"] = mode
        if mode == "exact":
            res = fitmod.fit_table(exact, fitmod.FitOptions(free=("kappa_eq", "r_en")))
        elif mode == "exacteiv":
            res = fitmod.fit_table(exact, fitmod.FitOptions(free=("kappa_eq", "r_en"), base=Params(gps_sigma=0.01, gps_ratio=1.0, attitude_sigma=0.0)))
        elif mode[-3:] in ("_sg", "_sp", "_sm"):
            from bench.fit.likelihood import simulate
            mean, Ea, Va = STATE["oracle"]
            truth = Params(kappa_eq=1.542, r_en=80.0, pose_sigma=0.0)
            rng = np.random.default_rng(seed + 77)
            if mode.endswith("_sg"):
                geo = geometry(mean, table.rx_quat, table.tx_pos, table.tx_quat)
                rr = rotation_components(unit_quaternion_components(table.rx_quat, "rx_q"))
                mm = x_axis_components(unit_quaternion_components(table.tx_quat, "tx_q"))
                a0 = _a((mean - table.tx_pos).T, mm, rr)
                sh_ = np.where(np.isfinite(Ea[0] - a0[0]), Ea[0] - a0[0], 0.0)
                d = simulate(geo, truth, rng, spread=(sh_, np.sqrt(Va[0])))
            elif mode.endswith("_sm"):  # pose part exact (posterior sample), EMI at the mean geometry
                geo = geometry(mean, table.rx_quat, table.tx_pos, table.tx_quat)
                rr = rotation_components(unit_quaternion_components(table.rx_quat, "rx_q"))
                mm = x_axis_components(unit_quaternion_components(table.tx_quat, "tx_q"))
                a0 = _a((mean - table.tx_pos).T, mm, rr)[0]
                a_s = _a((STATE["samp"] - table.tx_pos).T, mm, rr)[0]
                dd = np.where(np.isfinite(a_s - a0), a_s - a0, 0.0)
                d = simulate(geo, truth, rng, spread=(dd, np.zeros_like(dd)))
            else:
                geo = geometry(STATE["samp"], table.rx_quat, table.tx_pos, table.tx_quat)
                d = simulate(geo, truth, rng)
            import copy
            t2 = copy.copy(table); t2.d = d.astype(table.d.dtype)
            STATE["mode"] = mode[:-3]
            res = fitmod.fit_table(t2, fitmod.FitOptions(free=("kappa_eq", "r_en"), base=base))
        else:
            res = fitmod.fit_table(table, fitmod.FitOptions(free=("kappa_eq", "r_en"), base=base))
        row = {"sh": SH, "minutes": minutes, "seed": seed, "mode": mode, "conv": res.converged, "oracle_cpu": to}
        for k in TRUTH:
            row[k] = res.estimate[k]; row[k + "_se"] = res.se[k]
        out.write(json.dumps(row) + "\n"); out.flush()
        print(row, flush=True)

import os
OFF = int(os.environ.get("OFF", "9000"))
SH = float(os.environ.get("SH", "1.0"))
if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("minutes", type=float)
    ap.add_argument("first_seed", type=int)
    ap.add_argument("end_seed", type=int)
    ap.add_argument("modes", help="comma-separated: plain, omean, ovar, ofull, exact, exacteiv (+ _sg, _sp, _sm)")
    ap.add_argument("out", help="JSON lines appended here")
    a = ap.parse_args()
    minutes, seeds, modes, path = a.minutes, range(a.first_seed, a.end_seed), a.modes.split(","), a.out
    with open(path, "a") as f:
        for s in seeds:
            run(minutes, s, modes, f)
