"""Which one fast model path to keep (issue 30): general path only, numpy fast path,
compiled kernel; on the model alone and on a whole ``arva-emulate --speed 0`` run.

Usage: python tests/perf/fast_path_choice.py [--poses N] [--frames F] [--runs R]

The three configurations alternate, ``--runs`` times each; every figure is the median of
its runs, with the median 1-minute load average (os.getloadavg) seen at those runs (other
jobs share this 2-core machine). The model alone: ``measure`` on N poses x 4 static
transmitters (the paper's), pairs per CPU second of this thread (time.thread_time) and per
wall second. The whole process: epochs per CPU second (user + sys of the child) and per
wall second of ``arva-emulate --scene walk --port - --frames F --speed 0 > /dev/null``.
"General only" disables the fast path (``_FastTables.applies`` returns False) in this
process, and in the child through a ``python -c`` wrapper around emulator.cli.main.
Prints a markdown table; writes nothing.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(ROOT))

from emulator.receiver import model  # noqa: E402

PAPER_TX = np.array([[20, 5, 0], [10, 0, 1], [20, -20, -1], [-6, 5, 0]], dtype=float)
CONFIGS = ("general", "numpy", "compiled")
WRAPPER = ("import sys; from emulator.receiver import model; "
           "model._FastTables.applies = staticmethod(lambda p: False); "
           "from emulator.cli import main; sys.argv[0] = 'arva-emulate'; sys.exit(main())")


def set_config(config: str) -> None:
    model.KERNEL = "numpy" if config == "general" else config
    model._FastTables.applies = staticmethod(
        (lambda p: False) if config == "general" else ORIGINAL_APPLIES)


ORIGINAL_APPLIES = model._FastTables.applies


def time_model(rx_p, rx_q, tx_q) -> tuple[float, float]:
    c0, w0 = time.thread_time(), time.perf_counter()
    model.measure(rx_p, rx_q, PAPER_TX, tx_q)
    return time.thread_time() - c0, time.perf_counter() - w0


def time_emulate(config: str, scene: Path, frames: int) -> tuple[float, float]:
    args = ["--scene", str(scene), "--port", "-", "--frames", str(frames), "--speed", "0"]
    if config == "general":
        cmd = [sys.executable, "-c", WRAPPER] + args
    else:
        cmd = [str(Path(sys.executable).with_name("arva-emulate"))] + args
    env = {**os.environ, "ARVA_MODEL_KERNEL": "numpy" if config == "general" else config}
    with open(os.devnull, "wb") as null:
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=null, stderr=subprocess.DEVNULL, check=True, env=env)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), wall


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1_000_000)
    ap.add_argument("--frames", type=int, default=150_000)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args(argv)
    if not model.KERNEL_BUILT:
        sys.exit("fast_path_choice: the compiled kernel is not built (pip install -e . with a C compiler)")
    rng = np.random.default_rng(0)
    rx_p, rx_q = rng.uniform(-60, 60, (args.poses, 3)), rng.normal(size=(args.poses, 4))
    tx_q = np.tile([1.0, 0, 0, 0], (len(PAPER_TX), 1))
    pairs = args.poses * len(PAPER_TX)
    outs = {}
    for c in CONFIGS:  # same integers on every path
        set_config(c)
        outs[c] = model.measure(rx_p, rx_q, PAPER_TX, tx_q)
    same = all(np.array_equal(getattr(outs[c], f), getattr(outs["general"], f))
               for c in CONFIGS for f in ("d", "delta", "zone"))
    walk = (ROOT / "emulator" / "scenes" / "paper_walk.toml").read_text()
    res = {(k, c): [] for k in ("model", "emulate") for c in CONFIGS}
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "walk.toml"  # every epoch on the moving path
        scene.write_text(walk.replace("rate_hz = 1.0", f"rate_hz = {args.frames / 350.0}"))
        for _ in range(args.runs):
            for c in CONFIGS:
                set_config(c)
                cpu, wall = time_model(rx_p, rx_q, tx_q)
                res["model", c].append((pairs / cpu, pairs / wall, os.getloadavg()[0]))
                cpu, wall = time_emulate(c, scene, args.frames)
                res["emulate", c].append((args.frames / cpu, args.frames / wall, os.getloadavg()[0]))
    set_config("numpy")
    med = {key: [statistics.median(v[i] for v in runs) for i in range(3)] for key, runs in res.items()}
    print(f"{args.poses:,} poses x 4 tx; arva-emulate {args.frames:,} epochs (paper_walk, 4 tx, 4 channels); "
          f"median of {args.runs} alternating runs; same integers on all three paths: {same}\n")
    print("| what | path | per CPU second | per wall second | vs general (CPU) | load (1 min, median) |")
    print("|---|---|---|---|---|---|")
    for k, unit in (("model", "pairs/s"), ("emulate", "epochs/s")):
        for c in CONFIGS:
            cpu, wall, load = med[k, c]
            what = "`measure()` alone" if k == "model" else "`arva-emulate --speed 0`, whole process"
            print(f"| {what} | {c} | {cpu:,.0f} {unit} | {wall:,.0f} {unit} | "
                  f"{cpu / med[k, 'general'][0]:.2f}x | {load:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
