"""What accuracy costs in time: regenerates docs/accuracy.md (issue 8) with plots.

Usage: python tests/perf/accuracy_report.py [--n 1000] [--quick] [--only search]

Sections (each between ``<!-- BEGIN name -->`` / ``<!-- END name -->`` markers; only
these are rewritten, everything else in docs/accuracy.md is kept):

* ``fidelity`` (a): what each model-fidelity knob costs per epoch and what it changes —
  effects on/off, float32 versus float64 poses, path interpolation (static, waypoints,
  closed-loop vehicle) and the closed loop's control rate.
* ``calibration`` (b): written by ``tests/perf/accuracy_vs_minutes.py`` (the fit issue);
  this script runs it when it exists and never touches that section otherwise.
* ``search`` (c): search speed (v_max, k_c) versus final localisation error and
  time-to-locate, per strategy, from a seeded sweep of random burials.

Every number in those sections is measured by this command; plots go to docs/img/.
"""

from __future__ import annotations

import argparse
import math
import pickle
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parent), str(HERE)]  # the repository, tests/, tests/perf

from _report import ROOT, markdown_table, replace_section, stamped_block  # noqa: E402

from emulator.closed_loop.case_study import load_case  # noqa: E402
from emulator.closed_loop.loop import ClosedLoop  # noqa: E402
from emulator.receiver.model import measure  # noqa: E402
from emulator.receiver.receiver import Receiver  # noqa: E402
from emulator.scene.reader import loads_scene  # noqa: E402
from emulator.testing.scene_toml import dumps  # noqa: E402
from emulator.closed_loop.sweep import SweepConfig, SweepResult, summarize, summary_table, sweep, write_table  # noqa: E402
from emulator.frames.trajectory import Trajectory  # noqa: E402
from emulator.progress import progress  # noqa: E402

ACCURACY_MD = ROOT / "docs" / "accuracy.md"
IMG = ROOT / "docs" / "img"
SCRIPT = "python tests/perf/accuracy_report.py"
CALIBRATION_SCRIPT = HERE / "accuracy_vs_minutes.py"
SECTIONS = ("fidelity", "calibration", "search")
ROWS_FILE = "accuracy_search.parquet"

HEADER = """# What accuracy costs in time

Every accuracy knob of the emulator and of a search has a price in time: time per epoch
for the model's fidelity, minutes of field logging for the calibration, seconds of
flight for the localisation error. Each section below is measured by the script named
in it (`python tests/perf/accuracy_report.py` regenerates all of them and calls the
calibration script); the plots are in `docs/img/`. Re-run to refresh.
"""

PLACEHOLDER_CALIBRATION = """<!-- BEGIN calibration -->
## (b) Calibration accuracy versus minutes of logging

Not generated yet: this section is written by `tests/perf/accuracy_vs_minutes.py` (the
fit issue), which `python tests/perf/accuracy_report.py` runs when it exists.
<!-- END calibration -->
"""

#: The walk of section (a): the paper's four transmitters (m, the scene frame), the receiver
#: 1 m up on three north-south legs at 1 m/s (t in s), facing along its leg.
WALK_TRANSMITTERS = ([20.0, 5.0, 0.0], [10.0, 0.0, 1.0], [20.0, -20.0, -1.0], [-6.0, 5.0, 0.0])
_NORTH = [0.7071067811865476, 0.0, 0.0, 0.7071067811865476]
_SOUTH = [0.7071067811865476, 0.0, 0.0, -0.7071067811865476]
WALK_PATH = (
    (0.0, [-30.0, -40.0, 1.0], _NORTH), (80.0, [-30.0, 40.0, 1.0], _NORTH),
    (90.0, [-10.0, 40.0, 1.0], _SOUTH), (170.0, [-10.0, -40.0, 1.0], _SOUTH),
    (180.0, [10.0, -40.0, 1.0], _NORTH), (260.0, [10.0, 40.0, 1.0], _NORTH),
)


def walk_scene(noise=False, pulses=False, quantize=False, research=False, static=False):
    """The walk (or, ``static``, its first position held), with the effects named on."""
    scene: dict = {
        "spec": 1, "seed": 4, "rate_hz": 1.0, "model": {"r_en": 80.0},
        "effects": {"noise": noise, "pulses": pulses, "quantize": quantize, "research_sentences": research},
        "transmitters": [{"id": k, "position": p} for k, p in enumerate(WALK_TRANSMITTERS, 1)],
        "receiver": {"channels": 4},
    }
    if pulses:
        scene["pulses"] = {"period_ms": [700.0, 1300.0], "pulse_ms": 100.0}
    if quantize:
        scene["quantize"] = {"profile": "leds5"}
    if static:
        scene["receiver"]["position"] = list(WALK_PATH[0][1])
    else:
        scene["receiver"]["path"] = [{"t": t, "position": p, "orientation": q} for t, p, q in WALK_PATH]
    return loads_scene(dumps(scene), "<accuracy walk>")


def best_of(fn, repeat=3):
    """Smallest wall time of ``repeat`` calls, and the last result."""
    best, out = math.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def slots(epochs):
    return np.stack([epochs.ids, epochs.d, epochs.delta], axis=-1)


# --------------------------------------------------------------------------- (a)
def fidelity_effects(n_epochs: int):
    t = np.arange(n_epochs, dtype=np.float64)
    configs = [
        ("ideal receiver (no effects)", {}),
        ("+ noise (EMI, paper eqs. 3-5)", {"noise": True}),
        ("+ pulses (overlap, 700-1300 ms)", {"pulses": True}),
        ("+ quantize (5 direction LEDs)", {"quantize": True}),
        ("+ research field ($PARVH)", {"research": True}),
        ("all of the above", {"noise": True, "pulses": True, "quantize": True, "research": True}),
    ]
    ideal = None
    rows = []
    for name, kw in configs:
        scene = walk_scene(**kw)
        seconds, ep = best_of(lambda: Receiver(scene).evaluate(t))
        s = slots(ep)
        if ideal is None:
            ideal = s
        changed = np.any(s != ideal, axis=2).mean()  # per slot
        rows.append((name, 1e6 * seconds / n_epochs, changed))
    return rows


def fidelity_float(n: int):
    rng = np.random.default_rng(11)
    tx = np.array([[20.0, 5.0, 0.0], [10.0, 0.0, 1.0], [20.0, -20.0, -1.0], [-6.0, 5.0, 0.0]])
    q_tx = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    rx = rng.uniform(-50, 50, (n, 3))
    q = rng.standard_normal((n, 4))
    out = []
    for label, offset in (("local ENU (within 60 m of the origin)", 0.0), ("ENU origin 500 km away", 5e5)):
        p64, t64 = rx + offset, tx + offset
        t_64, m64 = best_of(lambda: measure(p64, q, t64, q_tx))
        p32, t32, q32 = p64.astype(np.float32), t64.astype(np.float32), q.astype(np.float32)
        t_32, m32 = best_of(lambda: measure(p32, q32, t32, q_tx.astype(np.float32)))
        diff = (m64.d != m32.d) | (m64.delta != m32.delta)
        zone = (m64.d < 0) != (m32.d < 0)
        both = (m64.d >= 0) & (m32.d >= 0)
        big = int(np.abs(m64.d - m32.d)[both].max())
        out.append((label, 1e9 * t_64 / (4 * n), 1e9 * t_32 / (4 * n), diff.mean(), zone.mean(), big))
    return out


def plain_measure(rx_p, rx_q, tx_p, tx_m, dtype):
    """The ideal receiver's (d, delta) by the textbook formulas (BRIEF 3, mid and inner
    zones, outer = -1) computed entirely in ``dtype``: no overflow guards, no scaling.

    For this report only: the model itself computes in float64 with guards
    (:mod:`emulator.receiver.model`); this is what a float32 pipeline such as arva_sim's does,
    timed against the same code in float64.
    """
    rx_p, rx_q, tx_p, tx_m = (np.asarray(a, dtype=dtype) for a in (rx_p, rx_q, tx_p, tx_m))
    w, x, y, z = (rx_q / np.sqrt((rx_q * rx_q).sum(axis=1, keepdims=True))).T
    # Receiver rotation R (body -> world), entries as (N, 1) columns.
    r = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]  # fmt: skip
    r = [[c[:, None] for c in row] for row in r]
    d = rx_p[:, None, :] - tx_p[None, :, :]
    dist = np.sqrt((d * d).sum(axis=2))
    n = d / dist[..., None]
    mx, my, mz = tx_m[:, 0], tx_m[:, 1], tx_m[:, 2]
    x3 = 3 * (n[..., 0] * mx + n[..., 1] * my + n[..., 2] * mz)
    u = (x3 * n[..., 0] - mx, x3 * n[..., 1] - my, x3 * n[..., 2] - mz)
    g0, g1, g2 = (r[0][j] * u[0] + r[1][j] * u[1] + r[2][j] * u[2] for j in range(3))
    scale = dtype(math.cbrt(1.542))
    d3 = dist * scale / np.cbrt(np.sqrt(g0 * g0 + g1 * g1 + g2 * g2))
    dxy = dist * scale / np.cbrt(np.sqrt(g0 * g0 + g1 * g1))
    inner = d3 <= 3.0
    outer = ~inner & ~(dxy <= 50.0)
    cm = np.where(inner, d3, dxy) * 100
    d_cm = np.where(outer, -1, np.floor(cm + 0.5).astype(np.int64))
    delta = np.clip(np.floor(np.degrees(np.arctan(g1 / g0)) + 0.5), -89, 89).astype(np.int64)
    delta = np.where(outer, -1, np.where(inner, 0, delta))
    return d_cm, delta


def fidelity_compute_dtype(n: int):
    """Computing in float32 versus float64: time of the same plain formulas in each, and
    how often each differs from the model (float64 with guards)."""
    rng = np.random.default_rng(12)
    tx = np.array([[20.0, 5.0, 0.0], [10.0, 0.0, 1.0], [20.0, -20.0, -1.0], [-6.0, 5.0, 0.0]])
    tx_m = np.tile([1.0, 0.0, 0.0], (4, 1))
    rx = rng.uniform(-50, 50, (n, 3))
    q = rng.standard_normal((n, 4))
    ref = measure(rx, q, tx, np.tile([1.0, 0.0, 0.0, 0.0], (4, 1)))
    rows = []
    for dtype in (np.float64, np.float32):
        with np.errstate(all="ignore"):
            seconds, (d, delta) = best_of(lambda: plain_measure(rx, q, tx, tx_m, dtype))
        changed = (d != ref.d) | (delta != ref.delta)
        both = (d >= 0) & (ref.d >= 0)
        rows.append((dtype.__name__, 1e9 * seconds / (4 * n), changed.mean(), int(np.abs(d - ref.d)[both].max())))
    return rows


def fidelity_paths(n_epochs: int):
    """Cost of the receiver's pose source, per epoch."""
    t = np.arange(n_epochs, dtype=np.float64)
    rows = []
    for name, scene in (("static pose", walk_scene(static=True)), ("waypoint path (linear + slerp)", walk_scene())):
        seconds, _ = best_of(lambda: Receiver(scene).evaluate(t))
        rows.append((name, 1e6 * seconds / n_epochs))
    scene = load_case(1)
    loop_epochs = 300

    def closed():
        loop = ClosedLoop(scene, record=False)
        for _ in range(loop_epochs):
            loop.step()

    seconds, _ = best_of(closed)
    rows.append(("closed-loop UAV + flux follower, 10 Hz control", 1e6 * seconds / loop_epochs))
    return rows


def fidelity_waypoints():
    """Sampling a curved flight (case 4, flux follower, 10 Hz) as waypoints every
    ``step`` seconds, then interpolating: how often the 1 Hz epochs change."""
    run = ClosedLoop(load_case(4)).run(60.0, stop_when_found=False)
    scene = load_case(4)
    truth_t = run.epoch_t
    rx = Receiver(scene)
    exact = rx.evaluate_poses(truth_t, run.position[::10], np.tile([1.0, 0.0, 0.0, 0.0], (len(truth_t), 1)))
    rows = []
    for step in (1, 2, 5, 10, 20):
        idx = np.arange(0, len(run.t), 10 * step)
        if idx[-1] != len(run.t) - 1:
            idx = np.append(idx, len(run.t) - 1)
        traj = Trajectory(run.t[idx], run.position[idx], np.tile([1.0, 0.0, 0.0, 0.0], (len(idx), 1)))
        pos, quat = traj.at(truth_t)
        ep = Receiver(scene).evaluate_poses(truth_t, pos, quat)
        err = np.linalg.norm(pos - run.position[::10], axis=1)
        changed = (ep.d != exact.d).any(axis=1)
        rows.append((step, err.max(), changed.mean(), int(np.abs(ep.d - exact.d).max())))
    return rows


def fidelity_control_rate():
    rows = []
    for rate in (1.0, 2.0, 5.0, 10.0, 50.0):
        scene = load_case(1, control_rate_hz=rate)
        seconds, run = best_of(lambda: ClosedLoop(scene, record=False).run(300.0))
        found = run.found()[0]
        epochs = run.t_end * scene.rate_hz
        rows.append((rate, 1e6 * seconds / epochs, found["t"], found["error_m"]))
    return rows


def plot_fidelity(effects, paths, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r[0] for r in effects] + [r[0] for r in paths]
    values = [r[1] for r in effects] + [r[1] for r in paths]
    colors = ["C0"] * len(effects) + ["C1"] * len(paths)
    fig, ax = plt.subplots(figsize=(9, 4.2))
    y = np.arange(len(names))[::-1]
    ax.barh(y, values, color=colors)
    for yi, v in zip(y, values):
        ax.text(v * 1.05, yi, f"{v:.2f} µs", va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("time per epoch [µs] (log)")
    ax.set_title("Model fidelity versus time per epoch (4 transmitters, 4 channels)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def captioned_table(caption: str, header: list[str], rows: list[list[object]]) -> list[str]:
    """The lines of a paragraph ``caption`` followed by its table, each closed by a blank line."""
    return [caption, "", markdown_table(header, rows), ""]


def section_fidelity(n_epochs: int, n_float: int) -> str:
    effects = fidelity_effects(n_epochs)
    floats = fidelity_float(n_float)
    dtypes = fidelity_compute_dtype(n_float)
    paths = fidelity_paths(n_epochs)
    waypoints = fidelity_waypoints()
    rates = fidelity_control_rate()
    IMG.mkdir(parents=True, exist_ok=True)
    plot_fidelity(effects, paths, IMG / "accuracy_fidelity.png")
    base = effects[0][1]
    parts = [
        "## (a) Model fidelity versus time per epoch",
        "",
        f"Receiver epochs of the paper's four transmitters on a {n_epochs}-epoch walk (4 channels), "
        "rendered in one batch as `arva-emulate --speed 0` does; best of 3. \"Slots changed\" is the "
        "fraction of (epoch, slot) whose (id, d, delta) differs from the ideal receiver's.",
        "",
        markdown_table(
            ["model", "time per epoch", "x ideal", "slots changed"],
            [[n, f"{us:.2f} µs", f"{us / base:.2f}", f"{100 * c:.1f} %"] for n, us, c in effects],
        ),
        "",
        "**float32 versus float64 poses** (`emulator.receiver.model.measure`, "
        f"{n_float:,} random poses x 4 transmitters; the model always computes in float64, so "
        "float32 only rounds the inputs, as a float32 pipeline such as arva_sim's would):",
        "",
        markdown_table(
            ["coordinates", "float64 inputs", "float32 inputs", "(d, delta) changed", "signal <-> no signal", "largest change of d"],
            [
                [lbl, f"{a:.1f} ns/pair", f"{b:.1f} ns/pair", f"{100 * c:.3f} %", f"{100 * z:.3f} %", f"{m} cm"]
                for lbl, a, b, c, z, m in floats
            ],
        ),
        "",
        "**Computing in float32 versus float64** (the same plain formulas, no overflow guards, "
        f"in each type; {n_float:,} random poses x 4 transmitters within 60 m; compared with the "
        "model, which computes in float64 only; measured by `plain_measure` in this script):",
        "",
        markdown_table(
            ["computed in", "time", "(d, delta) differing from the model", "largest difference of d"],
            [[name, f"{ns:.1f} ns/pair", f"{100 * c:.3f} %", f"{m} cm"] for name, ns, c, m in dtypes],
        ),
        "",
        f"Computing in float32 takes {dtypes[1][1] / dtypes[0][1]:.2f}x the time of the same formulas in "
        "float64 and changes almost nothing near the origin; what float32 cannot hold is "
        "coordinates far from it (the 500 km row above), which is why the model stays float64.",
        "",
        "**Where the receiver's pose comes from**, per epoch (batch of "
        f"{n_epochs} for the first two; the closed loop renders epoch by epoch):",
        "",
        markdown_table(["pose source", "time per epoch"], [[n, f"{us:.2f} µs"] for n, us in paths]),
        "",
        *captioned_table(
            "**Path interpolation fidelity**: the case-4 flight (flux follower, 60 s, positions at "
            "10 Hz) resampled as waypoints every N seconds and interpolated linearly, as a scene "
            "`path` does, versus the exact positions, at the 1 Hz epochs:",
            ["waypoint every", "largest position error", "epochs with a different d", "largest d change"],
            [[f"{s} s", f"{e:.3f} m", f"{100 * c:.1f} %", f"{m} cm"] for s, e, c, m in waypoints],
        ),
        *captioned_table(
            "**Closed-loop control rate** (case 1, flux follower, 1 Hz receiver; the vehicle and "
            "the height hold step at the control rate):",
            ["control rate", "wall time per epoch", "located at", "horizontal error"],
            [[f"{r:g} Hz", f"{us:.0f} µs", f"{t:.1f} s", f"{e:.3f} m"] for r, us, t, e in rates],
        ),
        "![model fidelity versus time per epoch](img/accuracy_fidelity.png)",
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------- (c)
def plot_search(summary, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    strategies = sorted({s["strategy"] for s in summary})
    k_cs = sorted({s["k_c"] for s in summary})
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.3), sharey=False)
    markers = dict(zip(k_cs, "os^Dv"))
    for ax, strategy in zip(axes, strategies):
        for k in k_cs:
            pts = sorted((s["v_max"], s) for s in summary if s["strategy"] == strategy and s["k_c"] == k)
            x = [s["t_locate_median_s"] for _, s in pts]
            y = [s["error_median_m"] for _, s in pts]
            ax.plot(x, y, "-" + markers[k], label=f"k_c = {k:g}")
            for (v, s), xi, yi in zip(pts, x, y):
                ax.annotate(f"{v:g} m/s\n{100 * s['located']:.0f} %", (xi, yi), fontsize=7,
                            textcoords="offset points", xytext=(4, 2))
        ax.set_title(strategy)
        ax.set_xlabel("median time to locate [s]")
        ax.set_ylabel("median horizontal error [m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Search speed versus localisation error (labels: v_max, located fraction)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def sweep_in_parts(config: SweepConfig, cache: Path | None):
    """The sweep of ``config``, one (strategy, v_max) at a time; with ``cache``, each part's
    rows are kept there (pickled) and reused, so an interrupted run resumes and a
    partial one can be reported (``--partial``)."""
    rows, scene_s, wall, executor, done = [], 0.0, 0.0, "", []
    # Fastest searches first, every strategy at each speed: a partial run covers them all.
    for v in sorted(config.v_max, reverse=True):
        for strategy in config.strategies:
            part = replace(config, strategies=(strategy,), v_max=(v,))
            file = None if cache is None else cache / f"search_{config.seed}_{config.n}_{strategy}_{v:g}.pickle"
            if file is not None and file.exists():
                r = pickle.loads(file.read_bytes())
            else:
                if file is not None and PARTIAL:
                    continue
                with progress(f"accuracy: search {strategy} {v:g} m/s", total=len(part.tasks()), unit="runs") as bar:
                    res = sweep(part, progress=bar)
                r = (res.rows, res.scene_s, res.wall_s, res.executor)
                if file is not None:
                    cache.mkdir(parents=True, exist_ok=True)
                    file.write_bytes(pickle.dumps(r))
            rows += r[0]
            scene_s += r[1]
            wall += r[2]
            executor = r[3]
            done.append((strategy, v))
            print(f"search: {strategy} v_max {v:g} done ({len(rows)} rows)", flush=True)
    rows.sort(key=lambda r: (config.strategies.index(r["strategy"]), r["v_max"], r["k_c"], r["burial"], r["tx_id"]))
    summary = summarize(rows, config.bootstrap, config.seed)
    return SweepResult(config, rows, summary, wall, scene_s, executor), done


#: Report only the parts already in the cache (set by --partial).
PARTIAL = False


def section_search(n: int, v_max, k_c, seed: int, cache: Path | None = None) -> str:
    config = SweepConfig(n=n, seed=seed, v_max=tuple(v_max), k_c=tuple(k_c))
    result, done = sweep_in_parts(config, cache)
    everything = len(done) == len(config.strategies) * len(config.v_max)
    ran = "" if everything else (
        " **Partial run:** only these (strategy, v_max) parts finished in the time we had: "
        + ", ".join(f"{s} {v:g} m/s" for s, v in done) + "."
    )
    IMG.mkdir(parents=True, exist_ok=True)
    plot_search(result.summary, IMG / "accuracy_search.png")
    (ROOT / "docs" / "data").mkdir(parents=True, exist_ok=True)
    old_csv = ROOT / "docs" / "data" / "accuracy_search.csv"
    if old_csv.exists():
        old_csv.unlink()  # superseded by the Parquet table (10^5 rows are ~10 MB of CSV)
    write_table(result.rows, ROOT / "docs" / "data" / ROWS_FILE)
    summary = result.summary
    best = {}
    for s in summary:
        if s["located"] == max(x["located"] for x in summary if x["strategy"] == s["strategy"]):
            b = best.get(s["strategy"])
            if b is None or s["t_locate_median_s"] < b["t_locate_median_s"]:
                best[s["strategy"]] = s
    lines = [
        f"- **{k}**: its best located fraction, {100 * s['located']:.1f} %, is reached fastest at v_max = "
        f"{s['v_max']:g} m/s, k_c = {s['k_c']:g}: median {s['t_locate_median_s']:.0f} s to locate, median error "
        f"{s['error_median_m']:.2f} m (p90 {s['error_p90_m']:.2f} m)."
        for k, s in sorted(best.items())
    ]
    parts = [
        "## (c) Search speed versus localisation error and time to locate",
        "",
        f"`emulator.closed_loop.sweep`: {n} seeded random burials (seed {seed}; 1-4 transmitters uniform in an "
        f"80 m x 80 m area, {config.depth[0]:g}-{config.depth[1]:g} m deep, uniformly random "
        "orientations, EMI noise on), flown by each strategy at each (v_max, k_c) from the area's "
        "south-west corner: lawnmower strips 30 m apart until a signal, r_s = 1 m, 1 Hz receiver, "
        f"10 Hz control, {config.t_max:g} s budget per burial. *Located* counts transmitters; "
        "times are scene seconds from the start; the error is horizontal, from the reported "
        "position to the transmitter.",
        "",
        f"{len({(r['strategy'], r['v_max'], r['k_c'], r['burial']) for r in result.rows})} runs, "
        f"{result.scene_s:,.0f} s of scene time in {result.wall_s:.0f} s of wall time "
        f"({result.speedup:,.0f}x real time, {result.executor}, batch engine; measured while other jobs shared "
        f"the 2 cores). Rows: `docs/data/{ROWS_FILE}` (the `arva-sweep` columns).{ran}",
        "",
        summary_table(summary),
        "",
        "Tails: p99 and maximum over the *located* transmitters of a cell (a transmitter never "
        "located has no time and no error; see the located column). The bracketed ranges are "
        f"95 % percentile-bootstrap intervals of the p99 ({config.bootstrap} resamples of the "
        "burials, seeded: the transmitters of one burial share a search, so burials are the "
        "resampling unit). The maximum's bootstrap interval is degenerate (a resample never "
        "exceeds the sample maximum), so it is not printed; read a maximum as *at least*. "
        "With about 2,500 located transmitters per cell a p99 rests on ~25 values.",
        "",
        *lines,
        "",
        "Strategies: `flux` is the paper's eq. 10 on the full field vector (+h only); "
        "`flux_reverse` the same, following -h while |h| keeps falling; `receiver_only` uses "
        "(d, delta) alone like a rescuer (flux following by delta, then bracketing). See "
        "[closed_loop.md](closed_loop.md).",
        "",
        "![search speed versus localisation error](img/accuracy_search.png)",
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------- the file
def write_section(name: str, body: str) -> None:
    """Replace section ``name`` of docs/accuracy.md, or insert it in SECTIONS order."""
    later = SECTIONS[SECTIONS.index(name) + 1 :]
    replace_section(ACCURACY_MD, name, stamped_block(name, body, SCRIPT), before=later, header=HEADER)


def calibration() -> str:
    """Run the fit issue's script (it writes its own section); report what happened."""
    if CALIBRATION_SCRIPT.exists():
        proc = subprocess.run([sys.executable, str(CALIBRATION_SCRIPT)], cwd=ROOT, timeout=3600)
        return f"{CALIBRATION_SCRIPT.name} exited {proc.returncode}"
    text = ACCURACY_MD.read_text() if ACCURACY_MD.exists() else HEADER
    if "<!-- BEGIN calibration -->" not in text:
        # A placeholder between the markers the calibration script owns; never a rewrite.
        at = text.find("<!-- BEGIN search -->")
        text = text.rstrip("\n") + "\n\n" + PLACEHOLDER_CALIBRATION if at < 0 else (
            text[:at] + PLACEHOLDER_CALIBRATION + "\n" + text[at:]
        )
        ACCURACY_MD.write_text(text)
        return "calibration script not present: placeholder section"
    return "calibration script not present: section left as it is"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=1000, help="burials per (strategy, v_max, k_c) (default 1000)")
    p.add_argument("--seed", type=int, default=8)
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    p.add_argument("--only", choices=SECTIONS, help="regenerate one section")
    p.add_argument("--cache", type=Path, help="(c): keep each (strategy, v_max) part's rows here and reuse them")
    p.add_argument("--partial", action="store_true", help="(c): report only the parts already in --cache")
    args = p.parse_args(argv)
    global PARTIAL
    PARTIAL = args.partial
    n_epochs, n_float = (1024, 20_000) if args.quick else (4096, 400_000)
    n = 4 if args.quick else args.n
    v_max, k_c = ((1.0, 2.0), (0.2,)) if args.quick else ((0.5, 1.0, 2.0, 4.0), (0.1, 0.2, 0.4))
    t0 = time.perf_counter()
    if args.only in (None, "fidelity"):
        with progress("accuracy: fidelity"):
            body = section_fidelity(n_epochs, n_float)
        write_section("fidelity", body)
        print(f"fidelity: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.only in (None, "calibration"):
        print(f"calibration: {calibration()}", flush=True)
    if args.only in (None, "search"):
        write_section("search", section_search(n, v_max, k_c, args.seed, args.cache))
        print(f"search: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"wrote {ACCURACY_MD.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
