"""Closed-loop sweep throughput: scene-seconds flown per second, per engine and executor.

Usage: python tests/perf/bench_sweep.py [--n 2000] [--n-run 24] [--no-dask]

For ``receiver_only`` and ``flux_reverse`` (the issue's target: at least 100,000
scene-seconds per wall-second on 2 cores) and ``flux``, seeded burials as ``arva-sweep``
flies them (80 m x 80 m, 1-4 transmitters, EMI noise on, 1800 s budget):

1. the per-run engine (``ClosedLoop``, one run after the other) in this process, per
   CPU-second of this process;
2. the batch engine (``BatchLoop``) in this process: per CPU-second and per wall-second;
3. the batch engine on the local process pool with 2 workers (one batch each): per
   wall-second, and per CPU-second of the two workers;
4. the batch engine on a Dask ``LocalCluster`` with 1 and with 2 worker processes (one
   thread each): per wall-second, and the scaling from 1 to 2 workers.

Each configuration runs once (a sweep of --n burials is several seconds of steady work).
Prints a table and rewrites its section of docs/performance.md with the load average
(other work on the machine lowers every wall-clock figure; the per-CPU-second ones
less so). About 1.5 minutes on 2 idle cores with the defaults.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import markdown_table, write_section  # noqa: E402

from emulator.closed_loop.sweep import SweepConfig, sweep  # noqa: E402

STRATEGIES = ("receiver_only", "flux_reverse", "flux")
#: The issue's target, scene-seconds per wall-second on 2 cores.
TARGET = 100_000


def children_cpu() -> float:
    t = os.times()
    return t.children_user + t.children_system


def timed(config: SweepConfig, **kw) -> tuple[float, float, float, float]:
    """(scene s, wall s, CPU s of this process, CPU s of reaped child processes) of one sweep."""
    cpu, kids = time.process_time(), children_cpu()
    result = sweep(config, **kw)
    return result.scene_s, result.wall_s, time.process_time() - cpu, children_cpu() - kids


def rate(x: float) -> str:
    return f"{x:,.0f}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=2000, help="burials per strategy, batch engine (default 2000)")
    p.add_argument("--n-run", type=int, default=24, help="burials per strategy, per-run engine (default 24)")
    p.add_argument("--seed", type=int, default=21)
    p.add_argument("--no-dask", action="store_true")
    args = p.parse_args(argv)
    started = time.perf_counter()
    loads = [os.getloadavg()[0]]
    configs = {s: SweepConfig(n=args.n, seed=args.seed, strategies=(s,), bootstrap=0) for s in STRATEGIES}
    res: dict[str, dict[str, float]] = {s: {} for s in STRATEGIES}
    for s, base in configs.items():
        r = res[s]
        s_run, _, c_run, _ = timed(replace(base, n=args.n_run, engine="run"), workers=1)
        r["run_cpu"] = s_run / c_run
        s_b, w_b, c_b, _ = timed(base, workers=1)
        r["batch_cpu"], r["batch_wall"] = s_b / c_b, s_b / w_b
        s_p, w_p, _, k_p = timed(base, workers=2)
        r["pool_wall"], r["pool_cpu"] = s_p / w_p, s_p / k_p if k_p > 0 else float("nan")
        loads.append(os.getloadavg()[0])
        print(s, {k: round(v) for k, v in r.items()}, f"load {loads[-1]:.1f}", flush=True)
    if not args.no_dask:
        from distributed import LocalCluster

        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
                sweep(replace(configs["flux"], n=2), scheduler=cl.scheduler_address)  # workers import everything
                for s, base in configs.items():
                    s_d, w_d, _, _ = timed(base, scheduler=cl.scheduler_address)
                    res[s][f"dask{workers}"] = s_d / w_d
                    print(s, f"dask x{workers}: {s_d / w_d:,.0f}", flush=True)
            loads.append(os.getloadavg()[0])
    header = ["strategy", "per-run engine, per CPU-s", "batch engine, per CPU-s", "batch / per-run",
              "batch, 1 process, per wall-s", "batch, pool x2, per wall-s", "pool x2 / 1 process",
              "pool x2, per worker CPU-s"]
    if not args.no_dask:
        header += ["Dask 1 worker, per wall-s", "Dask 2 workers, per wall-s", "Dask 2 / 1"]
    rows = []
    for s in STRATEGIES:
        r = res[s]
        row = [s, rate(r["run_cpu"]), rate(r["batch_cpu"]), f"x{r['batch_cpu'] / r['run_cpu']:.0f}",
               rate(r["batch_wall"]), rate(r["pool_wall"]), f"x{r['pool_wall'] / r['batch_wall']:.2f}",
               rate(r["pool_cpu"])]
        if not args.no_dask:
            row += [rate(r["dask1"]), rate(r["dask2"]), f"x{r['dask2'] / r['dask1']:.2f}"]
        rows.append(row)
    table = markdown_table(header, rows)
    print(table)
    total = time.perf_counter() - started
    verdict = []
    for s in ("receiver_only", "flux_reverse"):
        best = max(res[s]["pool_wall"], res[s].get("dask2", 0.0))
        verdict.append(f"{s} {best:,.0f} ({'meets' if best >= TARGET else 'below'} the target)")
    now = dt.datetime.now(dt.timezone.utc).strftime("%H:%M UTC")
    body = "\n".join([
        "Scene-seconds flown per second (higher is better) by `arva-sweep`'s engines: seeded burials "
        f"(seed {args.seed}; 80 m x 80 m, 1-4 transmitters, EMI noise on, 1800 s budget, lawnmower then "
        f"the strategy), {args.n:,} burials per strategy for the batch engine and {args.n_run} for the "
        "per-run engine (`--engine run`, the reference, which gives the same rows: "
        "tests/emulator/closed_loop/test_batch_loop.py). \"Per CPU-s\": scene-seconds per CPU-second of the process(es) "
        "that flew them, the engine's own cost. The process pool and Dask run one batch per worker "
        "(`arva-sweep`'s chunking); Dask: a `LocalCluster` of 1 or 2 worker processes with one "
        "thread each, warmed up by a tiny sweep first. Runs drop out of a batch as they finish, so "
        "its last epochs carry few runs (flux_reverse has a long tail of runs that fly to the "
        "budget): larger sweeps amortise better.",
        "",
        table,
        "",
        f"Target: at least {TARGET:,} scene-seconds per wall-second on 2 cores for receiver_only and "
        f"flux_reverse. Best 2-worker figure here (pool or Dask): {'; '.join(verdict)}.",
        "",
        f"Load average (1-minute) during the run, finished at {now}: "
        + ", ".join(f"{x:.1f}" for x in loads)
        + f" (before, after each strategy, after each Dask cluster); {total:.0f} s in all. A load "
        "above 0 means other jobs shared the 2 cores: wall-clock rates and the 1 -> 2 scaling are then "
        "bounded by what they left, and per-CPU-second rates drop too (shared caches, hyper-threads).",
    ])
    write_section("sweep", "Closed-loop sweep throughput", body, "python tests/perf/bench_sweep.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
