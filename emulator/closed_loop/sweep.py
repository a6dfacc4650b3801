"""Search sweeps: N seeded random burials per strategy, in closed loop, faster than real time.

docs/closed_loop.md, "Sweeps", describes the burials, the rows (:data:`COLUMNS`), the
summary and the command line (``python -m emulator.closed_loop.sweep``, ``arva-sweep``).
Burial i is drawn from ``SeedSequence(seed, spawn_key=(i,))`` (positions ENU metres,
depths metres below a flat snow surface, uniform random orientations) and every
strategy and (v_max, k_c) flies the same burials, so a sweep is a pure function of its
config: the same rows on one process, a pool or a Dask cluster. Engines: ``batch``
(:class:`~emulator.closed_loop.batch.BatchLoop`, a task's runs together) and ``run``
(:class:`~emulator.closed_loop.loop.ClosedLoop` one by one, the reference) give the
same rows, bit for bit (``tests/emulator/closed_loop/test_batch_loop.py``).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from emulator.cli_types import (
    OneLineParser, choice_list, integer, output_file, probe_writable, real, real_list, run_main, scheduler_address, seed,
)
from firmware_proto.errors import InputError, LinkError, MissingExtra

from emulator.closed_loop.batch import run_batch
from emulator.closed_loop.loop import ClosedLoop
from emulator.progress import Tracker
from emulator.progress import progress as progress_bar
from emulator.scene.reader import parse_scene

#: One row per (strategy, v_max, k_c, burial, transmitter).
COLUMNS = (
    "strategy", "v_max", "k_c", "burial", "n_tx", "tx_id", "tx_x", "tx_y", "depth_m",
    "found", "t_found_s", "error_m", "all_found", "t_all_s", "t_end_s", "path_m",
)


#: Sweep engines: runs stepped together (the default) or one by one (the reference).
ENGINES = ("batch", "run")

#: How long to wait for a dask scheduler before giving up (s).
SCHEDULER_TIMEOUT_S = 10.0

#: Strategy name -> the vehicle's controller (flux_reverse: eq. 10 with sign reversal).
STRATEGIES = {"flux": "flux", "flux_reverse": "flux", "receiver_only": "receiver_only"}


@dataclass(frozen=True)
class SweepConfig:
    n: int = 100
    seed: int = 0
    strategies: tuple[str, ...] = ("flux", "flux_reverse", "receiver_only")
    v_max: tuple[float, ...] = (1.0,)
    k_c: tuple[float, ...] = (0.2,)
    area: tuple[float, float, float, float] = (0.0, 0.0, 80.0, 80.0)
    max_transmitters: int = 4
    depth: tuple[float, float] = (0.3, 2.5)
    strip_width: float = 30.0
    r_s: float = 1.0
    k_z: float = 1.0
    noise: bool = True
    rate_hz: float = 1.0
    control_rate_hz: float = 10.0
    t_max: float = 1800.0
    chunk: int = 0  # runs per task; 0: one per worker, at most MAX_CHUNK
    engine: str = "batch"  # "batch": BatchLoop, runs stepped together; "run": ClosedLoop one by one
    bootstrap: int = 1000  # resamples for the tail statistics' confidence intervals
    antennas: int = 3  # receiver class (emulator.receiver.model.ModelParams.antennas)

    def tasks(self) -> list[tuple[str, float, float, int]]:
        return [
            (s, v, k, i) for s in self.strategies for v in self.v_max for k in self.k_c for i in range(self.n)
        ]


@dataclass
class SweepResult:
    config: SweepConfig
    rows: list[dict]
    summary: list[dict]
    wall_s: float
    scene_s: float  # scene time flown in total
    executor: str = ""

    @property
    def speedup(self) -> float:
        """Scene seconds per wall-clock second, over the whole sweep."""
        return self.scene_s / self.wall_s if self.wall_s > 0 else math.inf


# --------------------------------------------------------------------------- burials
def burial(config: SweepConfig, i: int) -> list[dict]:
    """The transmitters of burial ``i``: [{id, position, orientation, depth}]."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(i,)))
    n_tx = int(rng.integers(1, config.max_transmitters + 1))
    xmin, ymin, xmax, ymax = config.area
    out = []
    for j in range(n_tx):
        x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        depth = rng.uniform(*config.depth)
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        out.append({"id": j + 1, "position": [float(x), float(y), -float(depth)],
                    "orientation": [float(c) for c in q], "depth": float(depth)})
    return out


def burial_scene(config: SweepConfig, i: int, strategy: str, v_max: float, k_c: float):
    """The validated closed-loop scene of one run."""
    txs = burial(config, i)
    seed = int(np.random.SeedSequence(config.seed, spawn_key=(i, 1)).generate_state(1)[0])
    xmin, ymin = config.area[:2]
    data = {
        "spec": 1, "seed": seed, "rate_hz": config.rate_hz, "effects": {"noise": config.noise},
        "transmitters": [{k: tx[k] for k in ("id", "position", "orientation")} for tx in txs],
        "receiver": {
            "channels": config.max_transmitters, "antennas": config.antennas,
            "vehicle": {
                "controller": STRATEGIES[strategy], "start": [xmin, ymin], "r_s": config.r_s, "v_max": v_max,
                "k_c": k_c, "k_z": config.k_z, "control_rate_hz": config.control_rate_hz,
                "search_area": list(config.area), "strip_width": config.strip_width,
                **({"flux_reverse": True} if strategy == "flux_reverse" else {}),
            },
        },
    }
    return parse_scene(data, f"<sweep burial {i}>"), txs


def run_rows(strategy: str, v_max: float, k_c: float, i: int, txs: list[dict], result) -> list[dict]:
    """The :data:`COLUMNS` rows of burial ``i``'s :class:`RunResult`."""
    found = result.found()
    all_found = all(f["found"] for f in found)
    t_all = max(f["t"] for f in found) if all_found else math.nan
    return [{
        "strategy": strategy, "v_max": v_max, "k_c": k_c, "burial": i, "n_tx": len(txs),
        "tx_id": tx["id"], "tx_x": tx["position"][0], "tx_y": tx["position"][1], "depth_m": tx["depth"],
        "found": f["found"], "t_found_s": f["t"], "error_m": f["error_m"],
        "all_found": all_found, "t_all_s": t_all, "t_end_s": result.t_end, "path_m": result.path_length,
    } for tx, f in zip(txs, found)]


def run_chunk(config: SweepConfig, tasks: list[tuple[str, float, float, int]]) -> tuple[list[dict], float]:
    """Several runs in one worker call: with the batch engine flown together
    (:class:`BatchLoop`; strategies and gains may differ within a batch), else one after
    the other with the per-run :class:`ClosedLoop`. The rows in task order and the scene
    time flown."""
    made = [burial_scene(config, i, strategy, v_max, k_c) for strategy, v_max, k_c, i in tasks]
    scenes = [scene for scene, _ in made]
    if config.engine == "run":
        results = [ClosedLoop(scene, record=False).run(config.t_max) for scene in scenes]
    else:
        results = run_batch(scenes, config.t_max)
    rows = [row for task, (_, txs), result in zip(tasks, made, results) for row in run_rows(*task, txs, result)]
    return rows, sum(r.t_end for r in results)


#: Largest number of runs per task with the batch engine (memory stays ~100 MB).
MAX_CHUNK = 2048


def chunk_size(config: SweepConfig, n_tasks: int, workers: int) -> int:
    """Runs per task: ``config.chunk``, or one batch per worker, at most MAX_CHUNK. A
    batch is faster the larger it is: each one pays a fixed cost per epoch, all the more
    in its tail (the last runs, flying to ``t_max``), so splitting a worker's share in
    two would pay that tail twice."""
    if config.chunk > 0:
        return config.chunk
    if config.engine == "run":
        return 8
    return max(1, min(MAX_CHUNK, math.ceil(n_tasks / max(1, workers))))


# --------------------------------------------------------------------------- executors
def sweep(
    config: SweepConfig, workers: int | None = None, scheduler: str | None = None, progress: Tracker | None = None
) -> SweepResult:
    """Run every task of ``config``: in this process (``workers=1``), on a local process
    pool (default: one worker per CPU) or, given ``scheduler`` ("tcp://host:8786"), on a
    dask.distributed cluster. Rows come back in task order whatever the executor.
    ``progress`` is told the runs done and the scene-time rate as chunks finish."""
    if config.engine not in ENGINES:
        raise InputError(f"engine: unknown {config.engine!r} (known: {', '.join(ENGINES)})")
    tasks = config.tasks()
    wall = time.perf_counter()
    progress = progress or Tracker()
    scene_done = 0.0

    def done(part: tuple[list[dict], float], runs: int) -> tuple[list[dict], float]:
        nonlocal scene_done
        scene_done += part[1]
        rate = scene_done / max(time.perf_counter() - wall, 1e-9)
        progress.advance(runs, note=f"{rate:,.0f}x real time")
        return part
    if scheduler is not None:
        try:
            from distributed import Client, as_completed
        except ImportError:
            raise MissingExtra("--scheduler (a dask cluster)", "dask.distributed", "cluster") from None

        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise LinkError(f"--scheduler {scheduler}: cannot reach it within {SCHEDULER_TIMEOUT_S:g} s ({exc})") from None
        except Exception as exc:  # noqa: BLE001  something answered, but not a dask scheduler
            raise LinkError(f"--scheduler {scheduler}: not a dask scheduler ({type(exc).__name__})") from None
        with client:
            size = chunk_size(config, len(tasks), max(1, sum(client.nthreads().values())))
            chunks = [tasks[i : i + size] for i in range(0, len(tasks), size)]
            futures = client.map(run_chunk, [config] * len(chunks), chunks, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            parts = [None] * len(chunks)
            for f in as_completed(futures):
                i = index[f.key]
                parts[i] = done(f.result(), len(chunks[i]))
        executor = f"dask {scheduler}"
    else:
        workers = workers or os.cpu_count() or 1
        size = chunk_size(config, len(tasks), workers)
        chunks = [tasks[i : i + size] for i in range(0, len(tasks), size)]
        if workers == 1 or len(chunks) == 1:
            parts = [done(run_chunk(config, c), len(c)) for c in chunks]
            executor = "in process"
        else:
            workers = min(workers, len(chunks))
            with ProcessPoolExecutor(max_workers=workers) as pool:
                parts = [done(p, len(c)) for p, c in zip(pool.map(run_chunk, [config] * len(chunks), chunks), chunks)]
            executor = f"process pool x{workers}"
    wall = time.perf_counter() - wall
    rows = [row for part, _ in parts for row in part]
    scene_s = sum(t for _, t in parts)
    return SweepResult(config, rows, summarize(rows, config.bootstrap, config.seed), wall, scene_s, executor)


# --------------------------------------------------------------------------- summary
def _q(values: list[float], q: float) -> float:
    return float(np.quantile(values, q)) if values else math.nan


#: Two-sided level of the bootstrap intervals.
CI_LEVEL = 0.95


def bootstrap_tail(
    burial: np.ndarray, values: np.ndarray, n_burials: int, resamples: int, seed: int
) -> dict[str, tuple[float, float]]:
    """Percentile-bootstrap intervals (level :data:`CI_LEVEL`) of the p99 and the maximum
    of ``values`` (one per located transmitter, ``burial`` its burial index 0..n-1).

    Burials are resampled with replacement (the transmitters of one burial share its
    search, so they are not independent): resample b weights each value by how often its
    burial was drawn, and its p99 is the weighted inverted-CDF quantile. Seeded: the
    same rows give the same intervals. The maximum's interval is degenerate at the top
    (a resample never exceeds the sample maximum): read it as "at least".
    """
    out = {"p99": (math.nan, math.nan), "max": (math.nan, math.nan)}
    if values.size == 0 or resamples < 1:
        return out
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xB007,)))
    order = np.argsort(values, kind="stable")
    v, b = values[order], burial[order]
    p99 = np.empty(resamples)
    top = np.empty(resamples)
    step = max(1, 4_000_000 // max(n_burials + v.size, 1))
    for lo in range(0, resamples, step):
        k = min(step, resamples - lo)
        counts = rng.multinomial(n_burials, np.full(n_burials, 1.0 / n_burials), size=k)  # (k, n_burials)
        w = counts[:, b].astype(np.float64)  # (k, values) in sorted order
        cw = np.cumsum(w, axis=1)
        total = cw[:, -1]
        has = total > 0
        idx = np.argmax(cw >= 0.99 * total[:, None], axis=1)
        p99[lo : lo + k] = np.where(has, v[idx], np.nan)
        last = v.size - 1 - np.argmax(w[:, ::-1] > 0, axis=1)
        top[lo : lo + k] = np.where(has, v[last], np.nan)
    a = (1.0 - CI_LEVEL) / 2.0
    for name, stat in (("p99", p99), ("max", top)):
        stat = stat[np.isfinite(stat)]
        if stat.size:
            out[name] = (float(np.quantile(stat, a)), float(np.quantile(stat, 1.0 - a)))
    return out


def summarize(rows: list[dict], bootstrap: int = 1000, seed: int = 0) -> list[dict]:
    """Per (strategy, v_max, k_c): runs, located fraction, time-to-locate and error —
    median, p90, p99 and maximum over the located transmitters, the p99 and maximum with
    ``bootstrap``-resample confidence intervals (:func:`bootstrap_tail`, seeded by ``seed``)."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["strategy"], row["v_max"], row["k_c"]), []).append(row)
    out = []
    for (strategy, v_max, k_c), rs in groups.items():
        runs = {r["burial"]: r for r in rs}  # a run's columns (all_found, t_all_s) are on each of its rows
        found = [r for r in rs if r["found"]]
        t_found = [r["t_found_s"] for r in found]
        errors = [r["error_m"] for r in found]
        t_all = [r["t_all_s"] for r in runs.values() if r["all_found"]]
        index = {b: k for k, b in enumerate(runs)}
        which = np.array([index[r["burial"]] for r in found], dtype=np.int64)
        ci_t = bootstrap_tail(which, np.array(t_found, dtype=np.float64), len(runs), bootstrap, seed)
        ci_e = bootstrap_tail(which, np.array(errors, dtype=np.float64), len(runs), bootstrap, seed + 1)
        all_located = sum(r["all_found"] for r in runs.values()) / len(runs)
        out.append({
            "strategy": strategy, "v_max": v_max, "k_c": k_c, "runs": len(runs), "transmitters": len(rs),
            "located": len(found) / len(rs), "all_located": all_located,
            "t_locate_median_s": _q(t_found, 0.5), "t_locate_p90_s": _q(t_found, 0.9),
            "t_locate_p99_s": _q(t_found, 0.99), "t_locate_p99_ci_s": ci_t["p99"],
            "t_locate_max_s": max(t_found) if t_found else math.nan, "t_locate_max_ci_s": ci_t["max"],
            "t_all_median_s": _q(t_all, 0.5), "t_all_p90_s": _q(t_all, 0.9),
            "error_median_m": _q(errors, 0.5), "error_p90_m": _q(errors, 0.9),
            "error_p99_m": _q(errors, 0.99), "error_p99_ci_m": ci_e["p99"],
            "error_max_m": max(errors) if errors else math.nan, "error_max_ci_m": ci_e["max"],
            "within_1m": sum(e <= 1.0 for e in errors) / len(rs),
        })
    return out


def _pyarrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise MissingExtra("Parquet output", "pyarrow", "parquet") from None
    return pa, pq


def write_table(rows: list[dict], path: str | Path) -> None:
    """CSV (header :data:`COLUMNS`), or Parquet for ``*.parquet`` (the ``parquet`` extra),
    with the same columns in the same order (NaN where a CSV cell is empty)."""
    path = Path(path)
    if path.suffix == ".parquet":
        pa, pq = _pyarrow()
        columns = {k: [row[k] for row in rows] for k in COLUMNS}
        pq.write_table(pa.table(columns), path)
        return
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow({k: _fmt(row[k]) for k in COLUMNS})


def _fmt(v):
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(round(v, 6))
    return v


def _ci(pair: tuple[float, float], fmt: str) -> str:
    lo, hi = pair
    return "-" if math.isnan(lo) else f"[{lo:{fmt}}, {hi:{fmt}}]"


def summary_table(summary: list[dict]) -> str:
    """Markdown: one line per (strategy, v_max, k_c); tails with their 95 % intervals."""
    head = ("| strategy | v_max | k_c | runs | tx | located | all located | t locate median / p90 [s] "
            "| t all median / p90 [s] | error median / p90 / max [m] | t locate p99 [95 % CI] / max [s] "
            "| error p99 [95 % CI] [m] |")
    lines = [head, "|" + "---|" * 12]
    for s in summary:
        lines.append(
            f"| {s['strategy']} | {s['v_max']:g} | {s['k_c']:g} | {s['runs']} | {s['transmitters']} | "
            f"{100 * s['located']:.1f} % | {100 * s['all_located']:.1f} % | "
            f"{s['t_locate_median_s']:.0f} / {s['t_locate_p90_s']:.0f} | {s['t_all_median_s']:.0f} / {s['t_all_p90_s']:.0f} | "
            f"{s['error_median_m']:.2f} / {s['error_p90_m']:.2f} / {s['error_max_m']:.2f} | "
            f"{s['t_locate_p99_s']:.0f} {_ci(s['t_locate_p99_ci_s'], '.0f')} / {s['t_locate_max_s']:.0f} | "
            f"{s['error_p99_m']:.2f} {_ci(s['error_p99_ci_m'], '.2f')} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- CLI
#: Option ranges: a sweep is hours at most, not years; an area a drone can fly.
MAX_RUNS = 1_000_000
MAX_T_MAX_S = 86_400.0
MAX_AREA_M = 10_000.0
MAX_V_MAX = 20.0  # m/s (a scene's receiver.vehicle.v_max may go to 100)
MAX_K_C = 100.0


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="arva-sweep", description="Seeded random burials per search strategy, in closed loop.")
    p.add_argument("--n", type=integer(1, MAX_RUNS), default=100, help="burials per strategy and gain (default 100)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--strategies", type=choice_list(STRATEGIES, "strategy"), default=tuple(STRATEGIES),
                   help="comma-separated (default: all three)")
    p.add_argument("--v-max", type=real_list(1, 64, 0.0, MAX_V_MAX, lo_open=True), default=(1.0,),
                   help=f"m/s, comma-separated grid in (0, {MAX_V_MAX:g}] (default 1)")
    p.add_argument("--k-c", type=real_list(1, 64, 0.0, MAX_K_C, lo_open=True), default=(0.2,),
                   help="eq. 10 gain, comma-separated grid (default 0.2)")
    p.add_argument("--area", type=real_list(2, 2, 0.0, MAX_AREA_M, lo_open=True), default=(80.0, 80.0),
                   help=f"search area WIDTH,HEIGHT in m, each in (0, {MAX_AREA_M:g}] (default 80,80)")
    p.add_argument("--max-transmitters", type=integer(1, 99), default=4)
    p.add_argument("--t-max", type=real(0.0, MAX_T_MAX_S, lo_open=True), default=1800.0,
                   help=f"scene-time budget per run, s, in (0, {MAX_T_MAX_S:g}]")
    p.add_argument("--no-noise", action="store_true", help="ideal receiver (EMI noise off)")
    p.add_argument("--engine", choices=ENGINES, default="batch",
                   help="batch: runs of one strategy stepped together (default); run: one by one (the reference)")
    p.add_argument("--bootstrap", type=integer(0, 100_000), default=1000, help="resamples for the p99/max confidence intervals (default 1000)")
    p.add_argument("--antennas", type=int, choices=(2, 3), default=3, help="receiver class (default 3)")
    p.add_argument("--workers", type=integer(1, 1024), help="local processes (default: CPU count)")
    p.add_argument("--scheduler", type=scheduler_address, help="dask.distributed scheduler address, e.g. tcp://host:8786")
    p.add_argument("--out", type=output_file((".csv", ".parquet")),
                   help="write the rows here (.csv, or .parquet with the parquet extra)")
    return p


def run(args: argparse.Namespace) -> int:
    config = SweepConfig(
        n=args.n, seed=args.seed, strategies=args.strategies, v_max=args.v_max, k_c=args.k_c,
        area=(0.0, 0.0, *args.area), max_transmitters=args.max_transmitters, t_max=args.t_max,
        noise=not args.no_noise, engine=args.engine, bootstrap=args.bootstrap, antennas=args.antennas,
    )
    if args.out is not None:  # refused before hours of work, not after (--out's type checked the name)
        if args.out.suffix == ".parquet":
            _pyarrow()
        probe_writable(args.out, "--out")
    with progress_bar("arva-sweep", total=len(config.tasks()), unit="runs") as bar:
        result = sweep(config, workers=args.workers, scheduler=args.scheduler, progress=bar)
    if args.out is not None:
        write_table(result.rows, args.out)
    print(summary_table(result.summary))
    print(
        f"{len(config.tasks())} runs, {result.scene_s:,.0f} s of scene time in {result.wall_s:.1f} s "
        f"({result.speedup:,.0f}x real time, {result.executor})",
        file=sys.stderr,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("arva-sweep", lambda: build_parser().parse_args(argv), run)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
