"""Model and emulator throughput (issues 2, 20). Prints a table and writes docs/performance.md.

Usage: python tests/perf/bench_model.py [--poses N] [--rounds R]

* batch: emulator.receiver.model.measure on N receiver poses x 4 transmitters (pairs/s),
  once on its fast path (emulator/receiver/model/fast.py), once on the reference formula
  alone (``model.KERNEL = "general"``, as ARVA_MODEL_KERNEL=general sets it), and on the
  fast path with ``threads=2``;
* C loop: the general formulas in tests/perf/model_loop.c, compiled now with `cc -O3`;
* Python loop: tests/reference_model.measure per pair (a plain per-sample loop);
* arva-emulate --speed 0 > /dev/null, whole process, paper scene on a moving path, on
  each path (ARVA_MODEL_KERNEL=fast|general in its environment).

Batches and C loop are timed side by side, alternating, ``--rounds`` times each, best of
each kept, on this thread's CPU time (time.thread_time) as well as the wall clock: on a
host shared with other jobs the wall clock measures the load, CPU time the code. The
emulator's rate is likewise given per second of its CPU time (user + sys) and of wall time.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parent), str(HERE)]  # the repository, tests/, tests/perf

import reference_model  # noqa: E402
from _report import ROOT, markdown_table, write_section  # noqa: E402

from emulator.receiver import model  # noqa: E402
from emulator.receiver.model import CHUNK_PAIRS, ModelParams, measure  # noqa: E402
from emulator.frames.rotation import normalize_quaternions, quaternion_matrices  # noqa: E402
from emulator.output.scheduler import FAST_BATCH  # noqa: E402
from emulator.receiver.receiver import Receiver  # noqa: E402
from emulator.scene.reader import load_scene  # noqa: E402

PAPER_TX = np.array([[20, 5, 0], [10, 0, 1], [20, -20, -1], [-6, 5, 0]], dtype=float)


def poses(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-60, 60, (n, 3)), rng.normal(size=(n, 4))


def best_of(fn, repeat: int, clock=time.perf_counter) -> float:
    times = []
    for _ in range(repeat):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return min(times)


def c_loop(rx_p, rx_q, tx_q):
    """(call, note): the compiled C loop on these inputs, or (None, why not)."""
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
    # Inputs prepared outside the timed region (the batch call normalises its own quaternions).
    rx_r = np.ascontiguousarray(quaternion_matrices(normalize_quaternions(rx_q)))
    tx_r = np.ascontiguousarray(quaternion_matrices(normalize_quaternions(tx_q)))
    rx_c, tx_c = np.ascontiguousarray(rx_p), np.ascontiguousarray(PAPER_TX)
    d, delta = np.empty((n, m), np.int64), np.empty((n, m), np.int64)
    p = ModelParams()
    ptr = lambda a, t: a.ctypes.data_as(t)  # noqa: E731

    def call():
        so.model_loop(n, m, ptr(rx_c, dp), ptr(rx_r, dp), ptr(tx_c, dp), ptr(tx_r, dp),
                      p.distance_scale, p.r_inner, p.r_outer, ptr(d, ip), ptr(delta, ip))
        return d, delta

    return call, f"`{' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd[:5]))}`"


def with_kernel(kernel: str, fn):
    """fn run with ``model.KERNEL = kernel`` ("fast" or "general")."""
    def run():
        saved, model.KERNEL = model.KERNEL, kernel
        try:
            return fn()
        finally:
            model.KERNEL = saved
    return run


def side_by_side(rx_p, rx_q, tx_q, rounds: int) -> dict:
    """Best CPU and wall seconds of the batches (fast path, general path; fast with 2
    threads) and of the C loop, alternating."""
    call, note = c_loop(rx_p, rx_q, tx_q)
    one = lambda: measure(rx_p, rx_q, PAPER_TX, tx_q)  # noqa: E731
    two = lambda: measure(rx_p, rx_q, PAPER_TX, tx_q, threads=2)  # noqa: E731
    runs = {"fast": with_kernel("fast", one), "general": with_kernel("general", one),
            "2 threads": with_kernel("fast", two)}
    if call is not None:
        runs["C"] = call
    best = {k: [float("inf"), float("inf")] for k in runs}
    for _ in range(rounds):
        for name, fn in runs.items():
            cpu = time.process_time if "threads" in name else time.thread_time  # all threads' CPU
            c0, w0 = cpu(), time.perf_counter()
            fn()
            c1, w1 = cpu(), time.perf_counter()
            best[name][0] = min(best[name][0], c1 - c0)
            best[name][1] = min(best[name][1], w1 - w0)
    out = {"note": note, "best": best}
    ours = {k: runs[k]() for k in ("fast", "general")}
    out["mid"] = float(np.mean(ours["fast"].zone == 1))
    out["same"] = all(np.array_equal(getattr(ours["fast"], f), getattr(ours["general"], f))
                      for f in ("d", "delta", "zone"))
    if call is not None:
        d, delta = call()
        out["agree"] = float(np.mean((ours["fast"].d == d) & (ours["fast"].delta == delta)))
    return out


#: numpy passes of the batch's common path (the fast path, emulator/receiver/model/fast.py:
#: ideal receiver, 3 antennas, static transmitters, no field), counted from the code:
#: (what, passes per pair, passes per mid-zone pair, priced as). Per-pose work (quaternion
#: copy, |q|^2, two columns of R, R^T p_r, |p_r|^2: about 50 element passes per pose) is
#: shared by the M = 4 transmitters; sqrt, cbrt and atan run only for mid-zone pairs.
#: (Pairs near a boundary, and the rare inner ones, are batched once per call: not counted.)
PASSES = [
    ("add / subtract / multiply, pairs (G_x, G_y, |G_xy|^2, s^5, zone)", 13, 0, "add"),
    ("add / subtract / multiply, per pose / 4 (copies, |p_r|^2, R, R^T p_r)", 50 / 4, 0, "add"),
    ("divide (s^5 / |G_xy|^2; G_y / G_x for mid pairs)", 1, 1, "divide"),
    ("BLAS products (rows, 4|5) @ (4|5, M), per output: a_x, a_y, b_x, b_y, 3 m.d, s", 6, 0, "matmul"),
    ("compare + flatnonzero (mid zone; inner candidates)", 2, 0, "nonzero"),
    ("reduction (min / max of s, |q|^2)", 2 + 2 / 4, 0, "min"),
    ("fill outputs (d, delta: int64)", 2, 0, "fill"),
    ("gather / scatter by index (mid pairs: e, G_x, G_y in; d, delta out; delta table)", 0, 6, "gather"),
    ("add / multiply / floor / compare / casts, mid pairs (incl. the boundary checks)", 0, 22, "add"),
    ("sqrt", 0, 1, "sqrt"),
    ("cbrt", 0, 1, "cbrt"),
    ("arctan", 0, 1, "arctan"),
]


def ufunc_costs(size: int, m: int) -> dict[str, float]:
    """CPU ns per element of one numpy pass over a block of ``size`` float64 in cache."""
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0.5, 2.0, size), rng.uniform(0.5, 2.0, size)
    out, mask = np.empty(size), rng.uniform(size=size) < 0.25
    ints = np.empty(size, dtype=np.int64)
    idx = np.flatnonzero(mask)
    feats, coef = rng.uniform(size=(4, size // m)), rng.uniform(size=(4, m))
    prod = np.empty((size // m, m))
    ops = {
        "add": (lambda: np.add(a, b, out=out), size),
        "divide": (lambda: np.divide(a, b, out=out), size),
        "sqrt": (lambda: np.sqrt(a, out=out), size),
        "cbrt": (lambda: np.cbrt(a, out=out), size),
        "arctan": (lambda: np.arctan(a, out=out), size),
        "nonzero": (lambda: np.flatnonzero(np.less_equal(a, 1.0, out=mask)), size),
        "min": (lambda: a.min(), size),
        "fill": (lambda: ints.fill(-1), size),
        "matmul": (lambda: np.matmul(feats.T, coef, out=prod), size),
        "gather": (lambda: np.take(a, idx), idx.size),
    }
    reps = 100
    costs = {}
    for name, (fn, count) in ops.items():
        best = best_of(lambda: [fn() for _ in range(reps)], 5, clock=time.thread_time)
        costs[name] = best / reps / count * 1e9
    return costs


def floor_table(batch_ns: float, mid_fraction: float) -> tuple[str, float]:
    costs = ufunc_costs(CHUNK_PAIRS, len(PAPER_TX))
    rows, total = [], 0.0
    for what, per_pair, per_mid, op in PASSES:
        count = per_pair + per_mid * mid_fraction
        total += count * costs[op]
        rows.append([what, f"{per_pair:g} + {per_mid:g} x {mid_fraction:.2f}" if per_mid else f"{per_pair:g}",
                     f"{costs[op]:.2f} ns", f"{count * costs[op]:.1f} ns"])
    rows.append(["**sum: numpy's floor for this formulation**", "", "", f"**{total:.1f} ns**"])
    rows.append(["measured numpy batch (CPU time per pair, above)", "", "", f"{batch_ns:.1f} ns = {batch_ns / total:.2f}x the floor"])
    head = ["pass", "per pair (+ per mid pair x mid fraction)", "cost per element (block in cache)", "ns per pair"]
    return markdown_table(head, rows), total


def emulator_batches(frames: int, rate_hz: float, rounds: int) -> dict[str, float]:
    """Best CPU seconds per pair of ``measure`` on the emulator's own calls: FAST_BATCH
    epochs of paper_walk.toml (at ``rate_hz``, as bench_emulate runs it) x its 4
    transmitters, fast and general path alternating, 20 calls per timing."""
    rx = Receiver(load_scene(ROOT / "emulator" / "scenes" / "paper_walk.toml"))
    t = np.arange(min(frames, FAST_BATCH)) / rate_hz
    rx_p, rx_q = rx.trajectory.at(t)
    tx_p = np.stack([tx.trajectory.positions[0] for tx in rx.transmitters])
    tx_q = np.stack([tx.trajectory.orientations[0] for tx in rx.transmitters])
    pairs = len(t) * len(tx_p)
    calls = 20
    best = {k: float("inf") for k in model.KERNELS}
    for _ in range(rounds):
        for k in best:
            fn = with_kernel(k, lambda: [measure(rx_p, rx_q, tx_p, tx_q, rx.model) for _ in range(calls)])
            c0 = time.thread_time()
            fn()
            best[k] = min(best[k], (time.thread_time() - c0) / (calls * pairs))
    mid = float(np.mean(measure(rx_p, rx_q, tx_p, tx_q, rx.model).zone == 1))
    return {"pairs": pairs, "mid": mid, **best}


def bench_python(rx_p, rx_q, count: int):
    t0 = time.perf_counter()
    for i in range(count):
        for tx in PAPER_TX:
            reference_model.measure(rx_p[i], rx_q[i], tx)
    return count * len(PAPER_TX) / (time.perf_counter() - t0)


def bench_emulate(frames: int, rate_hz: float, kernel: str) -> tuple[float, float]:
    """(epochs per CPU second, epochs per wall second) of `arva-emulate --speed 0 > /dev/null`
    with ARVA_MODEL_KERNEL=``kernel`` ("fast" or "general")."""
    walk = (ROOT / "emulator" / "scenes" / "paper_walk.toml").read_text()
    with tempfile.TemporaryDirectory() as tmp:
        # Same walk, faster epochs, so every one of `frames` epochs is on the moving path.
        scene = Path(tmp) / "walk.toml"
        scene.write_text(walk.replace("rate_hz = 1.0", f"rate_hz = {rate_hz}"))
        exe = Path(sys.executable).with_name("arva-emulate")
        cmd = [str(exe), "--scene", str(scene), "--port", "-", "--frames", str(frames), "--speed", "0"]
        best_cpu = best_wall = float("inf")
        for _ in range(3):
            with open(os.devnull, "wb") as null:
                r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                subprocess.run(cmd, stdout=null, stderr=subprocess.DEVNULL, check=True,
                               env={**os.environ, "ARVA_MODEL_KERNEL": kernel})
                best_wall = min(best_wall, time.perf_counter() - t0)
                r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                best_cpu = min(best_cpu, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return frames / best_cpu, frames / best_wall


def startup_cpu() -> float:
    """CPU seconds of starting the interpreter and importing arva-emulate's modules."""
    best = float("inf")
    for _ in range(3):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, "-c", "import emulator.cli"], check=True)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        best = min(best, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1_000_000)
    ap.add_argument("--python-poses", type=int, default=20_000)
    ap.add_argument("--frames", type=int, default=150_000)
    ap.add_argument("--rounds", type=int, default=5, help="alternating timed runs of the batches and the C loop")
    ap.add_argument("--no-write", action="store_true", help="print only, leave docs/performance.md alone")
    args = ap.parse_args(argv)

    rx_p, rx_q = poses(args.poses)
    tx_q = np.tile([1.0, 0, 0, 0], (len(PAPER_TX), 1))
    load0 = os.getloadavg()[0]
    sbs = side_by_side(rx_p, rx_q, tx_q, args.rounds)
    py = bench_python(rx_p, rx_q, args.python_poses)
    kernels = list(model.KERNELS)  # fast, general
    emu = {k: bench_emulate(args.frames, args.frames / 350.0, k) for k in kernels}
    eb = emulator_batches(args.frames, args.frames / 350.0, args.rounds)
    start_cpu = startup_cpu()
    load1 = os.getloadavg()[0]
    pairs = args.poses * len(PAPER_TX)
    best = sbs["best"]
    rate = {k: (pairs / v[0], pairs / v[1]) for k, v in best.items()}
    c = rate.get("C")
    ns = lambda k: f"{best[k][0] / pairs * 1e9:.1f} ns"  # noqa: E731
    vs_c = lambda k: "-" if c is None else f"{rate[k][0] / c[0]:.2f}x"  # noqa: E731
    api = "batch API `emulator.receiver.model.measure`"
    rows = [
        [f"{api}, fast path, 1 thread", f"{rate['fast'][0]:,.0f} pairs/s", ns("fast"),
         f"{rate['fast'][1]:,.0f} pairs/s", vs_c("fast"),
         f"{args.poses:,} poses x 4 tx; emulator/receiver/model/fast.py (numpy), the default; "
         f"{rate['fast'][0] / rate['general'][0]:.2f}x the general path (CPU)"],
        [f"{api}, general path only, 1 thread", f"{rate['general'][0]:,.0f} pairs/s", ns("general"),
         f"{rate['general'][1]:,.0f} pairs/s", vs_c("general"),
         "ARVA_MODEL_KERNEL=general: the reference formula (model/reference.py) for every pair; same integers"
         + ("" if not sbs["same"] else ", checked here")],
        ["same (fast), `threads=2`", f"{rate['2 threads'][0]:,.0f} pairs/s (both threads' CPU)", ns("2 threads"),
         f"{rate['2 threads'][1]:,.0f} pairs/s", "-",
         f"wall-clock scaling vs 1 thread: {rate['2 threads'][1] / rate['fast'][1]:.2f}x on 2 shared cores"],
        ["plain C loop, `cc -O3`", "skipped" if c is None else f"{c[0]:,.0f} pairs/s", "-" if c is None else ns("C"),
         "-" if c is None else f"{c[1]:,.0f} pairs/s", "-" if c is None else "1.00x",
         sbs["note"] + ("" if c is None else f"; agrees with the batch API on {sbs['agree']:.6%} of pairs")],
        ["per-sample Python loop (tests/reference_model.py)", "-", "-", f"{py:,.0f} pairs/s", "-",
         f"{args.python_poses:,} poses x 4 tx; the fast batch is {rate['fast'][1] / py:,.0f}x faster (wall)"],
    ]
    for k in kernels:
        rows.append([f"{api} on the emulator's calls, {k} path", f"{1 / eb[k]:,.0f} pairs/s", f"{eb[k] * 1e9:.1f} ns", "-", "-",
                     f"{eb['pairs'] // 4:,} epochs of paper_walk.toml x 4 tx per call (arva-emulate --speed 0's batch), "
                     f"{eb['mid']:.0%} mid-zone pairs; ARVA_MODEL_KERNEL={k}"])
    for k in kernels:
        rows.append([f"`arva-emulate --speed 0 > /dev/null`, whole process, {k} path", f"{emu[k][0]:,.0f} epochs/s", "-",
                     f"{emu[k][1]:,.0f} epochs/s", "-",
                     f"{args.frames:,} epochs, 4 tx, 4 channels, moving path (paper_walk.toml); "
                     f"ARVA_MODEL_KERNEL={k}; CPU = user + sys of the process"])
    table = markdown_table(["what", "per CPU second", "CPU per pair", "per wall second", "vs the C loop (CPU)", "notes"], rows)
    print(table)
    ratio = lambda k: "n/a" if c is None else f"{rate[k][0] / c[0]:.2f}"  # noqa: E731
    emu_cpu = emu["fast"][0]
    targets = (
        f"Measured while other jobs shared the 2 cores (load average {load0:.1f} before, {load1:.1f} after): "
        "the batches and the C loop alternate, best of "
        f"{args.rounds} each, so all see the same machine. "
        "Targets: batch >= 0.5x the C loop (issue 2), >= 2x (issue 20); >= 100x the Python loop; "
        "arva-emulate >= 20,000 epochs/s (issue 2), >= 200,000 (issue 20). "
        f"Measured: batch/C = {ratio('fast')} fast path, {ratio('general')} general path (CPU time), "
        f"batch/Python = {rate['fast'][1] / py:,.0f}, "
        f"emulate = {emu_cpu:,.0f} epochs per CPU second on the fast path "
        f"({emu['fast'][1]:,.0f} per wall second under this load; {emu['general'][0]:,.0f} per CPU second "
        "on the general path). "
        f"Of the emulator's {args.frames / emu_cpu:.2f} s of CPU, {start_cpu:.2f} s is starting Python "
        "and importing its modules (numpy and ours; not scipy, whose spatial package alone took ~0.3 s): the process's floor, whatever the epochs cost; "
        f"the epochs themselves run at {args.frames / max(args.frames / emu_cpu - start_cpu, 1e-9):,.0f} per CPU second."
    )
    print(targets)
    floor, floor_ns = floor_table(best["fast"][0] / pairs * 1e9, sbs["mid"])
    print(floor)
    half = (f" 2x needs {best['C'][0] / pairs * 1e9 / 2:.1f} ns per pair (half the C loop's "
            f"{best['C'][0] / pairs * 1e9:.1f} ns)." if "C" in best else "")
    limits = (
        "**The machine's limit, fast path (the table above).** That batch is a sequence of numpy passes "
        f"over blocks of {CHUNK_PAIRS:,} pairs; the table counts them on the common path (the model's fast path: "
        "ideal receiver, 3 antennas, static transmitters; "
        f"{sbs['mid']:.0%} of these pairs are in the mid zone, the rest outer or inner) and prices "
        "each at its measured cost on a block that stays in cache (same run, same load). Their "
        f"sum, {floor_ns:.1f} ns, is what this formulation can reach in numpy on this machine; the "
        "batch's own time above it is Python's per-call overhead (about 85 numpy calls per block) "
        "and memory traffic (reading the poses, first touch of the fresh (N, M) outputs). "
        "The C loop (tests/perf/model_loop.c) is the general formulation: scalar libm sqrt and cbrt for "
        "d3 and again for dxy on every pair, and atan for the mid-zone ones; the fast path decides zones "
        "on (200 dxy)^6 = s^5 / |G_xy|^2 (no root at all for outer pairs), which is why it beats it. "
        "A compiled version of the fast path was measured and removed (issue 30, docs/architecture.md)." + half
    )
    print(limits)
    targets += "\n\n" + floor + "\n\n" + limits
    if not args.no_write:
        write_section("model", "Receiver model and emulator throughput", table + "\n\n" + targets,
                      "python tests/perf/bench_model.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
