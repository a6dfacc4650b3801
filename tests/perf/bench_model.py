"""Model and emulator throughput (issue 2). Prints a table and writes docs/performance.md.

Usage: python tests/perf/bench_model.py [--poses N]

* batch: emulator.receiver.model.measure on N receiver poses x 4 transmitters (pairs/s);
* C loop: the same formulas in tests/perf/model_loop.c, compiled now with `cc -O3`;
* Python loop: tests/reference_model.measure per pair (a plain per-sample loop);
* arva-emulate --speed 0 > /dev/null, whole process, paper scene on a moving path.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import reference_model  # noqa: E402
from _report import ROOT, markdown_table, write_section  # noqa: E402

from emulator.receiver.model import ModelParams, measure  # noqa: E402
from emulator.frames.rotation import normalize_quaternions, quaternion_matrices  # noqa: E402

PAPER_TX = np.array([[20, 5, 0], [10, 0, 1], [20, -20, -1], [-6, 5, 0]], dtype=float)


def poses(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-60, 60, (n, 3)), rng.normal(size=(n, 4))


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_batch(rx_p, rx_q, tx_q):
    seconds = best_of(lambda: measure(rx_p, rx_q, PAPER_TX, tx_q), 3)
    return rx_p.shape[0] * len(PAPER_TX) / seconds


def bench_c(rx_p, rx_q, tx_q):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None, "no C compiler found: skipped"
    build = Path(tempfile.mkdtemp(prefix="arva-bench-"))
    lib = build / "model_loop.so"
    cmd = [cc, "-O3", "-std=c99", "-D_DEFAULT_SOURCE", "-fPIC", "-shared", str(HERE / "model_loop.c"), "-o", str(lib), "-lm"]
    subprocess.run(cmd, check=True)
    so = ctypes.CDLL(str(lib))
    dp, ip = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)
    so.model_loop.argtypes = [ctypes.c_int64, ctypes.c_int64, dp, dp, dp, dp] + [ctypes.c_double] * 3 + [ip, ip]
    n, m = rx_p.shape[0], len(PAPER_TX)
    # Inputs prepared outside the timed region, as for the batch call's own matrices.
    rx_r = np.ascontiguousarray(quaternion_matrices(normalize_quaternions(rx_q)))
    tx_r = np.ascontiguousarray(quaternion_matrices(normalize_quaternions(tx_q)))
    rx_c, tx_c = np.ascontiguousarray(rx_p), np.ascontiguousarray(PAPER_TX)
    d, delta = np.empty((n, m), np.int64), np.empty((n, m), np.int64)
    p = ModelParams()
    ptr = lambda a, t: a.ctypes.data_as(t)  # noqa: E731

    def call():
        so.model_loop(n, m, ptr(rx_c, dp), ptr(rx_r, dp), ptr(tx_c, dp), ptr(tx_r, dp),
                      p.distance_scale, p.r_inner, p.r_outer, ptr(d, ip), ptr(delta, ip))

    seconds = best_of(call, 3)
    ours = measure(rx_p, rx_q, PAPER_TX, tx_q)
    agree = float(np.mean((ours.d == d) & (ours.delta == delta)))
    return n * m / seconds, f"`{' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd[:5]))}`; agrees with the batch API on {agree:.6%} of pairs"


def bench_python(rx_p, rx_q, count: int):
    t0 = time.perf_counter()
    for i in range(count):
        for tx in PAPER_TX:
            reference_model.measure(rx_p[i], rx_q[i], tx)
    return count * len(PAPER_TX) / (time.perf_counter() - t0)


def bench_emulate(frames: int, rate_hz: float) -> float:
    """epochs/s of the whole `arva-emulate --speed 0 > /dev/null` process."""
    walk = (ROOT / "emulator" / "scenes" / "paper_walk.toml").read_text()
    with tempfile.TemporaryDirectory() as tmp:
        # Same walk, faster epochs, so every one of `frames` epochs is on the moving path.
        scene = Path(tmp) / "walk.toml"
        scene.write_text(walk.replace("rate_hz = 1.0", f"rate_hz = {rate_hz}"))
        exe = Path(sys.executable).with_name("arva-emulate")
        cmd = [str(exe), "--scene", str(scene), "--port", "-", "--frames", str(frames), "--speed", "0"]
        best = float("inf")
        for _ in range(3):
            with open(os.devnull, "wb") as null:
                t0 = time.perf_counter()
                subprocess.run(cmd, stdout=null, check=True)
                best = min(best, time.perf_counter() - t0)
    return frames / best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1_000_000)
    ap.add_argument("--python-poses", type=int, default=20_000)
    ap.add_argument("--frames", type=int, default=150_000)
    ap.add_argument("--no-write", action="store_true", help="print only, leave docs/performance.md alone")
    args = ap.parse_args(argv)

    rx_p, rx_q = poses(args.poses)
    tx_q = np.tile([1.0, 0, 0, 0], (len(PAPER_TX), 1))
    batch = bench_batch(rx_p, rx_q, tx_q)
    c_rate, c_note = bench_c(rx_p, rx_q, tx_q)
    py = bench_python(rx_p, rx_q, args.python_poses)
    emu = bench_emulate(args.frames, rate_hz=args.frames / 350.0)

    rows = [
        ["batch API `emulator.receiver.model.measure` (numpy)", f"{batch:,.0f} pairs/s", "1.00x", f"{args.poses:,} poses x 4 tx"],
        ["plain C loop, `cc -O3`", "skipped" if c_rate is None else f"{c_rate:,.0f} pairs/s",
         "-" if c_rate is None else f"{batch / c_rate:.2f}x", c_note],
        ["per-sample Python loop (tests/reference_model.py)", f"{py:,.0f} pairs/s", f"{batch / py:,.0f}x",
         f"{args.python_poses:,} poses x 4 tx"],
        ["`arva-emulate --speed 0 > /dev/null`, whole process", f"{emu:,.0f} epochs/s", "-",
         f"{args.frames:,} epochs, 4 tx, 4 channels, moving path (paper_walk.toml)"],
    ]
    table = markdown_table(["what", "throughput", "batch / this", "notes"], rows)
    print(table)
    targets = (
        "Targets (issue 2): batch >= 0.5x the C loop, >= 100x the Python loop; "
        "arva-emulate >= 20,000 epochs/s. "
        f"Measured: batch/C = {'n/a' if c_rate is None else f'{batch / c_rate:.2f}'}, "
        f"batch/Python = {batch / py:,.0f}, emulate = {emu:,.0f} epochs/s."
    )
    print(targets)
    if not args.no_write:
        write_section("model", "Receiver model and emulator throughput", table + "\n\n" + targets,
                      "python tests/perf/bench_model.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
