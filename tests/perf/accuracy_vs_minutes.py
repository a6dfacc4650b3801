"""Calibration accuracy versus minutes of logging (issue 6 item 5).

Usage: python tests/perf/accuracy_vs_minutes.py [--seeds N] [--no-write]

Emulates campaigns of 2 to 60 minutes at 1 Hz (``tests/fit_campaign.py``: radial walks
around a buried transmitter, EMI on, kappa_eq = 1.542, r_en = 80 m), fits each one and
reports, per length, the 95 % confidence-interval width of each parameter (median over
seeds), the actual error, how often the interval covers the truth, and the fit time.
Writes the ``calibration`` section of docs/accuracy.md (other sections are kept) and
docs/img/accuracy_calibration.png, and the measured tables of docs/calibration.md
(between ``<!-- BEGIN measured -->`` and ``<!-- END measured -->``).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parent), str(HERE)]  # the repository, tests/, tests/perf

from _report import ROOT, git_revision, machine, markdown_table, replace_section, stamped_block  # noqa: E402

from fit_campaign import Walk, emulate_campaign  # noqa: E402
from bench.fit import fit_table  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402

ACCURACY_MD = ROOT / "docs" / "accuracy.md"
CALIBRATION_MD = ROOT / "docs" / "calibration.md"
PNG = ROOT / "docs" / "img" / "accuracy_calibration.png"
SCRIPT = "python tests/perf/accuracy_vs_minutes.py"
MINUTES = (2, 5, 10, 20, 30, 45, 60)
TRUTH = {"kappa_eq": 1.542, "r_en": 80.0}


def pose_error_block() -> str:
    """The pose-error part of section (b), kept as it is: tests/perf/accuracy_pose_error.py
    writes it (between its own markers)."""
    text = ACCURACY_MD.read_text() if ACCURACY_MD.exists() else ""
    begin, end = "<!-- BEGIN pose-error -->", "<!-- END pose-error -->"
    lead = "**With real ground truth.**"
    if begin in text and end in text and lead in text:
        return text[text.index(lead) : text.index(end) + len(end)]
    return f"{lead} See `python tests/perf/accuracy_pose_error.py`.\n\n{begin}\n{end}"


def study(seeds: int):
    out = []
    for minutes in MINUTES:
        est, se, times, conv, cens = [], [], [], 0, []
        for seed in range(seeds):
            table = emulate_campaign(minutes, ModelParams(**TRUTH), seed=5000 + seed)
            t0 = time.perf_counter()
            res = fit_table(table)
            times.append(time.perf_counter() - t0)
            cens.append(res.n_censored / res.n_rows)
            if not res.converged:
                continue
            conv += 1
            est.append([res.estimate[k] for k in TRUTH])
            se.append([res.se[k] for k in TRUTH])
        est, se = np.array(est).reshape(-1, 2), np.array(se).reshape(-1, 2)
        truth = np.array(list(TRUTH.values()))
        rel_err = est / truth - 1
        z = (est - truth) / se
        row = {
            "minutes": minutes,
            "rows": int(minutes * 60),
            "converged": conv,
            "seeds": seeds,
            "ci": np.median(2 * 1.96 * se / est, axis=0),  # relative widths
            "rmse": np.sqrt(np.mean(rel_err**2, axis=0)),
            "bias": np.mean(rel_err, axis=0),
            "cover": np.mean(np.abs(z) <= 1.96, axis=0),
            "rmsz": np.sqrt(np.mean(z * z, axis=0)),
            "time": float(np.median(times)),
            "censored": float(np.mean(cens)),
        }
        out.append(row)
        print(
            f"{minutes:>3} min: converged {conv}/{seeds}, CI95 kappa {100 * row['ci'][0]:.3f} %, r_en {100 * row['ci'][1]:.2f} %, "
            f"rmse {100 * row['rmse'][0]:.3f} % / {100 * row['rmse'][1]:.2f} %, cover {row['cover']}, rms z {row['rmsz']}, "
            f"{row['time']:.2f} s",
            flush=True,
        )
    return out


def naive_comparison(seeds: int):
    walks = [("1 to 80 m (the default walk)", Walk()), ("30 to 65 m (near the range limit)", Walk(r_min=30.0, r_max=65.0))]
    rows = []
    for label, walk in walks:
        ours, naive, cens = [], [], []
        for seed in range(seeds):
            res = fit_table(emulate_campaign(30, ModelParams(**TRUTH), seed=7000 + seed, walk=walk))
            ours.append([res.estimate[k] / TRUTH[k] - 1 for k in TRUTH])
            naive.append([res.naive[k] / TRUTH[k] - 1 for k in TRUTH])
            cens.append(res.n_censored / res.n_rows)
        ours, naive = 100 * np.array(ours), 100 * np.array(naive)
        for name, e in (("maximum likelihood (ours)", ours), ("least squares on detected rows", naive)):
            rows.append([
                label, f"{100 * np.mean(cens):.0f} %", name,
                f"{e[:, 0].mean():+.3f} % (sd {e[:, 0].std():.3f})", f"{e[:, 1].mean():+.2f} % (sd {e[:, 1].std():.2f})",
            ])  # fmt: skip
            print(*rows[-1], sep=" | ", flush=True)
    header = ["walk", "rows with d = -1", "estimator", "kappa_eq error", "r_en error"]
    return markdown_table(header, rows)


def plot(results) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no plot", file=sys.stderr)
        return False
    m = np.array([r["minutes"] for r in results], dtype=float)
    ci = np.array([r["ci"] for r in results]) * 50  # half-widths: +- 1.96 se, % of the value
    t = np.array([r["time"] for r in results])
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for j, (name, color) in enumerate((("kappa_eq", "tab:blue"), ("r_en", "tab:orange"))):
        ax.loglog(m, ci[:, j], "o-", color=color, label=f"{name}: ± 1.96 se")
        ax.loglog(m, ci[-1, j] * np.sqrt(m[-1] / m), ":", color=color, lw=1, label=f"{name}: 1/sqrt(minutes)")
    for level in (1.0, 2.0):
        ax.axhline(level, color="grey", lw=0.8, ls="--")
    ax.set_xticks(m, [f"{v:g}" for v in m])
    ax.minorticks_off()
    ax.set_xlabel("minutes of logging at 1 Hz")
    ax.set_ylabel("95 % interval, ± % of the value")
    ax.set_title("How long to walk")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax2.plot(m, t, "o-", color="black")
    ax2.set_xlabel("minutes of logging at 1 Hz")
    ax2.set_ylabel("fit time (s, median)")
    ax2.set_ylim(0, max(t) * 1.2)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    PNG.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(PNG, dpi=110)
    plt.close(fig)
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=16, help="campaigns per length (default 16)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    results = study(args.seeds)
    naive = naive_comparison(max(4, args.seeds // 2))
    have_png = False if args.no_write else plot(results)
    table = markdown_table(
        ["minutes", "rows", "converged", "kappa_eq: 95 % interval", "kappa_eq: rms error", "r_en: 95 % interval",
         "r_en: rms error", "intervals covering the truth (kappa_eq, r_en)", "fit time"],
        [[
            r["minutes"], r["rows"], f"{r['converged']}/{r['seeds']}",
            f"± {50 * r['ci'][0]:.3f} %", f"{100 * r['rmse'][0]:.3f} %",
            f"± {50 * r['ci'][1]:.2f} %", f"{100 * r['rmse'][1]:.2f} %",
            f"{100 * r['cover'][0]:.0f} %, {100 * r['cover'][1]:.0f} %", f"{r['time']:.2f} s",
        ] for r in results],
    )  # fmt: skip
    first_2 = next((r["minutes"] for r in results if 50 * r["ci"][1] <= 2.0), None)
    first_1 = next((r["minutes"] for r in results if 50 * r["ci"][1] <= 1.0), None)
    body = f"""## (b) Calibration accuracy versus minutes of logging

`arva-bench fit --gps-sigma 0 --attitude-sigma 0` (poses declared exact: the relative pose
error model) on emulated campaigns (`tests/fit_campaign.py`: radial walks from 1 to 80 m
at 1.1 m/s around a transmitter buried 1 m deep, hand-held orientations, one epoch per
second, EMI on; truth kappa_eq = 1.542, r_en = 80 m, exact poses), {args.seeds} seeds per
length. Interval: ± 1.96 standard errors (median over seeds, in % of the estimate); rms
error over the seeds; coverage: how often that interval contains the truth (95 % if the
standard errors were exact).

{table}

**How long to walk:** r_en to ± 2 % after {first_2} minutes, ± 1 % after {first_1} minutes;
kappa_eq to better than ± 0.1 % from the first minutes (every near reading pins it).
Both shrink like 1/sqrt(minutes) (dotted lines in the plot). The table above assumes exact poses.

{pose_error_block()}

{"![calibration accuracy versus minutes](img/accuracy_calibration.png)" if have_png or PNG.exists() else ""}
"""
    print(body)
    print(naive)
    if args.no_write:
        return 0
    today = _dt.date.today().isoformat()
    stamp = f"_Measured {today} on {machine()}, commit {git_revision()}, by `{SCRIPT}`._"
    replace_section(ACCURACY_MD, "calibration", stamped_block("calibration", body, SCRIPT), before=("search",),
                    header="# What accuracy costs in time\n")
    cover = markdown_table(
        ["minutes", "rms of (estimate - truth) / se: kappa_eq", "r_en", "within 1.96 se: kappa_eq", "r_en", "mean error: kappa_eq", "r_en"],
        [[r["minutes"], f"{r['rmsz'][0]:.2f}", f"{r['rmsz'][1]:.2f}", f"{100 * r['cover'][0]:.0f} %", f"{100 * r['cover'][1]:.0f} %",
          f"{100 * r['bias'][0]:+.4f} %", f"{100 * r['bias'][1]:+.3f} %"] for r in results],
    )  # fmt: skip
    measured = f"""<!-- BEGIN measured -->
### Measured: the naive regression's bias

30-minute campaigns, {max(4, args.seeds // 2)} seeds per walk, truth kappa_eq = 1.542, r_en = 80 m; errors are
mean (and standard deviation) over the seeds.

{naive}

### Measured: are the standard errors honest?

The campaigns of the table in [accuracy.md](accuracy.md), {args.seeds} seeds per length. With
exact standard errors the root mean square of (estimate - truth) / se is 1 and 95 % of
the ± 1.96 se intervals contain the truth.

{cover}

{stamp}
<!-- END measured -->
"""
    replace_section(CALIBRATION_MD, "measured", measured, header="# Calibration\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
