"""Pinpointing study: how far from the victim is each receiver class's signal maximum?

Usage: python tests/perf/pinpoint_study.py [--orientations 200] [--seed 1] [--no-write]

For burial depths D = 0.5 .. 3 m and transmitter orientations drawn uniformly over the
sphere (seeded), a level receiver on the snow surface z = 0 above a transmitter at
(0, 0, -D) reads d at every point of a grid; the *signal maximum* is where d is
smallest (where 1/d is largest). Its horizontal distance from (0, 0) over D is the
pinpointing offset the receiver leads a rescuer to. Per receiver class (2 and 3
antennas, :class:`emulator.receiver.model.ModelParams`) the script prints the median,
p90 and maximum of that fraction per depth, draws ``docs/img/pinpoint_study.png`` and
rewrites the ``pinpoint`` section of ``docs/model.md``.

How the maximum is found. The model's own integers are used (its zones, its outer
zone at h_xy = 0), but with every length scaled by 1000: kappa_eq x 1e9, r_inner and
r_outer x 1000, so d comes out in units of 10 um instead of 1 cm and the flat top of
the maximum is no longer a plateau of equal centimetres; zone decisions are the same.
A coarse grid (+-1.5 D, step D/40) finds the basin, a fine grid around it (step
D/2000) the maximum. Orientation: the dipole axis is uniform on the sphere (the field
is odd in the axis, |h| even, so the sign does not matter). The receiver is held
level (yaw does not change |h| or |h_xy|).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parent), str(HERE)]  # the repository, tests/, tests/perf

from _report import ROOT, markdown_table, replace_section, stamped_block  # noqa: E402

from emulator.receiver.model import ModelParams, measure  # noqa: E402

MODEL_MD = ROOT / "docs" / "model.md"
IMG = ROOT / "docs" / "img" / "pinpoint_study.png"
SCRIPT = "python tests/perf/pinpoint_study.py"
DEPTHS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
#: Ayuso et al. 2015: location error at the signal maximum, fraction of burial depth.
AYUSO = {2: 0.50, 3: 0.25}
SCALE = 1e5  # lengths x 1e5 in the model: d resolves 0.1 um


def axis_quaternions(axes: np.ndarray) -> np.ndarray:
    """Unit quaternions [w, x, y, z] turning body x onto each unit vector of ``axes``."""
    q = np.c_[1.0 + axes[:, 0], np.zeros(len(axes)), -axes[:, 2], axes[:, 1]]
    flip = axes[:, 0] < -1 + 1e-12  # x -> -x: half a turn about z
    q[flip] = (0.0, 0.0, 0.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def scaled(antennas: int) -> ModelParams:
    p = ModelParams(antennas=antennas)
    return ModelParams(kappa_eq=p.kappa_eq * SCALE**3, r_inner=p.r_inner * SCALE, r_outer=p.r_outer * SCALE,
                       antennas=antennas)  # fmt: skip


def _grid(cx: float, cy: float, half: float, n: int) -> np.ndarray:
    g = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(cx + g, cy + g)
    return np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]


def _argmin(d: np.ndarray) -> int:
    dd = np.where(d < 0, np.iinfo(np.int64).max, d)
    return int(np.argmin(dd)) if (dd < np.iinfo(np.int64).max).any() else -1


def offsets(depth: float, quats: np.ndarray, params: ModelParams) -> np.ndarray:
    """Horizontal offset / depth of the signal maximum for each transmitter orientation."""
    tx = [(0.0, 0.0, -depth)]
    level = (1.0, 0.0, 0.0, 0.0)
    coarse = _grid(0.0, 0.0, 1.5 * depth, 121)
    step = 3.0 * depth / 120
    out = np.full(len(quats), np.nan)
    # All orientations at once on the coarse grid (N points x M transmitters).
    m = measure(coarse, np.tile(level, (len(coarse), 1)), np.repeat(tx, len(quats), axis=0), quats, params)
    for j, q in enumerate(quats):
        i = _argmin(m.d[:, j])
        if i < 0:
            continue
        cx, cy = coarse[i, :2]
        for half, n in ((2 * step, 81), (step / 10, 81)):
            fine = _grid(cx, cy, half, n)
            mf = measure(fine, np.tile(level, (len(fine), 1)), tx, [q], params)
            k = _argmin(mf.d[:, 0])
            cx, cy = fine[k, :2]
        out[j] = np.hypot(cx, cy) / depth
    return out


def run(n_orient: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    axes = rng.standard_normal((n_orient, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    quats = axis_quaternions(axes)
    result = {"tilt_deg": np.degrees(np.arcsin(np.abs(axes[:, 2])))}
    for antennas in (2, 3):
        params = scaled(antennas)
        result[antennas] = {depth: offsets(depth, quats, params) for depth in DEPTHS}
    return result


def stats(x: np.ndarray) -> tuple[float, float, float]:
    return float(np.median(x)), float(np.quantile(x, 0.9)), float(np.max(x))


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.25, 1]})
    for antennas, color in ((2, "C3"), (3, "C0")):
        s = np.array([stats(result[antennas][d]) for d in DEPTHS])
        ax.plot(DEPTHS, s[:, 0], "-o", color=color, label=f"{antennas} antennas: median")
        ax.plot(DEPTHS, s[:, 1], "--s", color=color, label=f"{antennas} antennas: p90")
        ax.plot(DEPTHS, s[:, 2], ":^", color=color, label=f"{antennas} antennas: max")
        ax.axhline(AYUSO[antennas], color=color, lw=3, alpha=0.25,
                   label=f"Ayuso et al. 2015 bound, {antennas} antennas ({AYUSO[antennas]:.0%})")  # fmt: skip
    ax.set_xlabel("burial depth D [m]")
    ax.set_ylabel("horizontal offset of the signal maximum / D")
    ax.set_ylim(0, 0.8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="upper center")
    ax.set_title("Offset of the signal maximum, over the sphere of orientations", fontsize=9)
    for antennas, color in ((2, "C3"), (3, "C0")):
        for depth, marker in ((2.0, "o"), (3.0, "x")):
            bx.scatter(result["tilt_deg"], result[antennas][depth], s=10, marker=marker, color=color,
                       alpha=0.7 if depth == 2.0 else 0.4, label=f"{antennas} antennas, D = {depth:g} m")  # fmt: skip
    bx.set_xlabel("transmitter axis above horizontal [deg]")
    bx.set_ylabel("offset / D")
    bx.set_ylim(0, 0.8)
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7, loc="upper left")
    bx.set_title("per orientation (0 = horizontal, 90 = vertical transmitter)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--orientations", type=int, default=200)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-write", action="store_true", help="print only; leave docs/ alone")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    result = run(args.orientations, args.seed)
    wall = time.perf_counter() - t0
    rows = []
    for antennas in (2, 3):
        for depth in DEPTHS:
            med, p90, mx = stats(result[antennas][depth])
            rows.append([antennas, f"{depth:g}", f"{100 * med:.1f} %", f"{100 * p90:.1f} %", f"{100 * mx:.1f} %"])
        med, p90, mx = stats(np.concatenate(list(result[antennas].values())))
        rows.append([antennas, "all", f"**{100 * med:.1f} %**", f"**{100 * p90:.1f} %**", f"**{100 * mx:.1f} %**"])
    table = markdown_table(["antennas", "depth [m]", "median", "p90", "max"], rows)
    print(table)
    print(f"{args.orientations} orientations x {len(DEPTHS)} depths x 2 classes in {wall:.1f} s", file=sys.stderr)
    if args.no_write:
        return 0
    plot(result, IMG)
    body = (
        f"`{SCRIPT}`: {args.orientations} transmitter orientations uniform over the sphere (seed {args.seed}) "
        f"at each burial depth; a level receiver on the surface; the horizontal distance from the victim to "
        f"where d is smallest, as a fraction of the depth (method in the script's docstring). "
        f"Ayuso et al. 2015 bound it by 50 % for 1- and 2-antenna receivers and by 25 % for 3-antenna "
        f"receivers within the third antenna's range.\n\n"
        f"{table}\n\n![pinpointing offset versus depth](img/pinpoint_study.png)\n\n"
        f"Run time {wall:.0f} s (measured while other jobs shared the 2 cores)."
    )
    replace_section(MODEL_MD, "pinpoint", stamped_block("pinpoint", body, SCRIPT, verb="Generated"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
