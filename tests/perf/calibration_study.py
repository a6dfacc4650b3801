"""The calibration validation study (issue 28, item 7): `arva-bench fit` as a team runs it,
on independent campaigns (``study_campaigns.py``) with a hidden truth.

Each run writes one campaign's CSV and runs ``python -m bench.cli fit CSV --json`` (the
command line, with its defaults, unless a condition adds options), with a time limit;
one JSON line per run goes to ``--out``. The table per condition:

* ``conv``: converged (exit 0) out of the runs; ``crash``: no JSON at all (a traceback or
  a time-out), which a user sees as a broken tool;
* kappa_eq and r_en: mean error and RMS error (% of the truth), coverage of the
  printed 95 % interval (estimate +- 1.96 s.e.);
* ``silent``: converged, |z| > 3 for kappa_eq or r_en, and no warning note (a note is a
  warning unless it is one of the routine ones listed in ``ROUTINE``).

Seeds: ``--tuning`` draws seeds from 0 up (for development); without it, seeds start at
``REPORT_SEED0``. Numbers that go into the docs come from the report seeds only.

Usage::

    python tests/perf/calibration_study.py --seeds 50 --workers 2 [--conditions a,b] [--tuning]
    python tests/perf/calibration_study.py --table out.jsonl   # the table of earlier runs
    python tests/perf/calibration_study.py --docs   # the docs' study table from REPORT_RUNS
    python tests/perf/calibration_study.py --conditions level-heavy \
        --with "level-heavy:--fit gps_outlier"   # also a variant with these fit options

A ``--with COND:OPTIONS`` variant runs the condition's campaigns again with OPTIONS
added to the fit (after ``--extra``), reported as its own row, ``COND [OPTIONS]``.

``--docs`` writes the study table of docs/calibration.md and docs/accuracy.md (section
``study``) from the report runs kept in tests/perf/out and named in :data:`REPORT_RUNS`
(each row says which fit code ran it); it runs no fit.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import scipy.stats

sys.path.insert(0, str(Path(__file__).resolve().parent))

import study_campaigns as sc  # noqa: E402
from _report import git_revision, replace_section  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
REPORT_SEED0 = 1_000_000
TIMEOUT_S = 600.0
#: Notes that say how the fit ran, not that something is wrong with its numbers.
ROUTINE = (
    r"^Newton on a \d+-row subsample",
    r"^time offset: none found",
    r"rows changed likelihood regime at the estimate; refitted$",
    r"^each row's GPS error follows",
    r"rows left out: closer to the transmitter than the pose error lets the model place them$",
    r"is at its lower bound .*\(exact|is at its lower bound",
    r"^gps_outlier_scale is held at .* \(no GPS outliers are visible\)$",
    r"^the first search stopped .*; a restart from its point.* converged$",
    # the default fit refitted as exact poses (both pose-error sigmas on their floors): how
    # it ran, not a warning, so it must not hide a miss from the silent count
    r"^no pose error is visible \(GPS and attitude error at their floors, [^)]*\): fitted as exact poses",
    # the passes' attitude fixed point left for the floors (then fitted as exact poses): how it ran
    r"^the fit kept an attitude error of [0-9.]+ deg with no GPS error visible, but searched from the floors",
    # the default fit refitted with a dropout probability (spurious -1 rows): how it ran
    r"^spurious -1 rows: \d+ rows say 'nothing heard' .*; refitted with a dropout probability",
)


@dataclass(frozen=True)
class ReportRun:
    """A report-seed run (a jsonl of :func:`run_one` records in tests/perf/out) whose rows
    go into the docs' study table, and the fit code (commit) it ran."""

    file: str
    commit: str


#: The runs behind the docs' study table, oldest first: a condition (with its fit options)
#: found in a later run replaces the earlier run's row. Add a run here, then ``--docs``.
REPORT_RUNS = (
    ReportRun("calibration_study_4h_report50_594e36d.jsonl", "594e36d"),
    ReportRun("calibration_study_outlier_mount_f55577c.jsonl", "f55577c"),
    ReportRun("calibration_study_student_outlier_report20_9d73015.jsonl", "9d73015"),
    ReportRun("calibration_study_radial_far_exact_report50_ba05bac.jsonl", "ba05bac"),
    ReportRun("calibration_study_level_exact_report50_ba05bac.jsonl", "ba05bac"),
    ReportRun("calibration_study_radial_spiral_near_report50_10b68e2.jsonl", "10b68e2"),
    ReportRun("calibration_study_junk_drone_offset_far_level_report50_10b68e2.jsonl", "10b68e2"),
    ReportRun("calibration_study_heavy_student_mount_report50_10b68e2.jsonl", "10b68e2"),
    ReportRun("calibration_study_near_report50_29616eb.jsonl", "29616eb"),
    ReportRun("calibration_study_junk_dropout_report50_29616eb.jsonl", "29616eb"),
    ReportRun("calibration_study_heavy_junk_report50_134a440.jsonl", "134a440"),
    ReportRun("calibration_study_junk_report50_94214b2.jsonl", "94214b2"),
    ReportRun("calibration_study_student_outlier_report20_94214b2.jsonl", "94214b2"),
    ReportRun("calibration_study_fixedb_report50_c417b9f.jsonl", "c417b9f"),
    ReportRun("calibration_study_fixedb2_report50_c417b9f.jsonl", "c417b9f"),
    ReportRun("calibration_study_att_report50_aca882e.jsonl", "aca882e"),
    ReportRun("calibration_study_variants_report20_aca882e.jsonl", "aca882e"),
    ReportRun("calibration_study_dropout_report50_aca882e.jsonl", "aca882e"),
)
OUT = ROOT / "tests/perf/out"
DOCS = (ROOT / "docs/calibration.md", ROOT / "docs/accuracy.md")


def warning_notes(notes: list[str]) -> list[str]:
    return [n for n in notes if not any(re.search(p, n) for p in ROUTINE)]


def run_one(cond: sc.Condition, seed: int, extra: list[str], workdir: Path, label: str | None = None) -> dict:
    camp = sc.campaign(cond, seed)
    path = workdir / f"{cond.name}-{seed}-{abs(hash(label)) if label else 0}.csv"
    path.write_text(camp.csv_text())
    cmd = [sys.executable, "-m", "bench.cli", "fit", str(path), "--json", *extra]
    t0 = time.monotonic()
    rec: dict = {
        "condition": label or cond.name,
        "seed": seed,
        "truth": {"kappa_eq": camp.truth.kappa_eq, "r_en": camp.truth.r_en},
        "rows": int(len(camp.rows)),
        "heard": camp.heard,
        "extra": extra,
    }
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S, cwd=ROOT)
    except subprocess.TimeoutExpired:
        rec.update(status="timeout", wall=time.monotonic() - t0)
        path.unlink(missing_ok=True)
        return rec
    rec["wall"] = time.monotonic() - t0
    rec["exit"] = proc.returncode
    err = proc.stderr.strip().splitlines()
    rec["stderr_last"] = err[-1] if err else ""
    try:
        out = json.loads(proc.stdout)
    except ValueError:
        rec["status"] = "crash" if proc.returncode not in (2,) else "refused"
        path.unlink(missing_ok=True)
        return rec
    rec["status"] = "converged" if out.get("converged") else "not_converged"
    rec["fit"] = {k: out.get(k) for k in ("kappa_eq", "kappa_eq_se", "r_en", "r_en_se", "gps_sigma", "attitude_sigma", "time_offset", "separable", "fit_seconds", "message", "gps_outlier", "gps_outlier_scale", "mount_pitch", "mount_pitch_se", "mount_roll", "mount_roll_se")}
    rec["fit"]["gps_sigma_se"] = out.get("gps_sigma_se")
    rec["fit"]["attitude_sigma_se"] = out.get("attitude_sigma_se")
    gof = out.get("goodness_of_fit") or {}
    rec["fit"]["goodness_of_fit"] = {k: gof.get(k) for k in ("p_value", "fits", "worst", "unexpected_censored")} if gof else None
    rec["notes"] = out.get("notes", [])
    rec["warnings"] = warning_notes(rec["notes"]) + ([] if out.get("separable", True) else ["not separable"])
    path.unlink(missing_ok=True)
    return rec


def _z(rec: dict, name: str) -> float | None:
    f = rec.get("fit") or {}
    est, se = f.get(name), f.get(f"{name}_se")
    if est is None or se is None or not (se > 0):
        return None
    return (est - rec["truth"][name]) / se


def covered(conv: list[dict], name: str) -> tuple[int, int]:
    """Of the converged fits ``conv`` with a standard error for ``name``: how many intervals
    (estimate +- 1.96 s.e.) contain the truth, and how many there are."""
    zs = [z for z in (_z(r, name) for r in conv) if z is not None]
    return sum(abs(z) <= 1.96 for z in zs), len(zs)


def table(records: list[dict]) -> tuple[list[str], list[list[object]]]:
    header = [
        "condition", "runs", "conv %", "crash", "kappa bias %", "kappa RMS %", "kappa cover %",
        "r_en bias %", "r_en RMS %", "r_en cover %", "silent", "median s",
    ]
    by: dict[str, list[dict]] = {}
    for r in records:
        by.setdefault(r["condition"], []).append(r)
    rows = []
    for name, recs in by.items():
        conv = [r for r in recs if r.get("status") == "converged"]
        crash = sum(r.get("status") in ("crash", "timeout") for r in recs)
        cells: list[object] = [name, len(recs), f"{100 * len(conv) / len(recs):.0f}", crash]
        silent = 0
        for pname in ("kappa_eq", "r_en"):
            errs = [(r["fit"][pname] - r["truth"][pname]) / r["truth"][pname] for r in conv if r["fit"].get(pname) is not None]
            if errs:
                mean = 100 * sum(errs) / len(errs)
                rms = 100 * math.sqrt(sum(e * e for e in errs) / len(errs))
                k, n = covered(conv, pname)
                cover = 100 * k / n if n else float("nan")
                cells += [f"{mean:+.2f}", f"{rms:.2f}", f"{cover:.0f} ({k}/{n})"]
            else:
                cells += ["-", "-", "-"]
        for r in conv:
            zk, zr = _z(r, "kappa_eq"), _z(r, "r_en")
            # (the warnings from the notes under the current ROUTINE list, as run_one makes them)
            warned = warning_notes(r.get("notes", [])) or not (r.get("fit") or {}).get("separable", True)
            if ((zk is not None and abs(zk) > 3) or (zr is not None and abs(zr) > 3)) and not warned:
                silent += 1
        walls = sorted(r["wall"] for r in recs if "wall" in r)
        cells += [silent, f"{walls[len(walls) // 2]:.1f}" if walls else "-"]
        rows.append(cells)
    return header, rows


def extras_table(records: list[dict]) -> tuple[list[str], list[list[object]]] | None:
    """Per condition, of the converged fits: how many the goodness-of-fit check said do
    not fit, and the optional parameters where fitted: the mounting bias against the
    generator's (``study_campaigns.MOUNT_DEG``: mean, RMS error and coverage of the 95 %
    interval, deg) and the GPS outlier share and width (medians)."""
    by: dict[str, list[dict]] = {}
    for r in records:
        f = r.get("fit") or {}
        if r.get("status") == "converged":
            by.setdefault(r["condition"], []).append(f)
    if not by:
        return None
    header = ["condition", "fits", "misfit found", "pitch mean", "pitch RMS", "pitch cover %", "roll mean", "roll RMS", "roll cover %",
              "outlier share (median)", "outlier width (median)"]  # fmt: skip
    rows = []
    for name, fits in by.items():
        gof = [f["goodness_of_fit"] for f in fits if f.get("goodness_of_fit")]
        cells: list[object] = [name, len(fits), f"{sum(not g.get('fits', True) for g in gof)}/{len(gof)}"]
        for key, truth in zip(("mount_pitch", "mount_roll"), sc.MOUNT_DEG):
            got = [(math.degrees(f[key]), math.degrees(f[f"{key}_se"])) for f in fits if f.get(key) is not None and f.get(f"{key}_se")]
            if got and "mount" in name:
                errs = [v - truth for v, _s in got]
                cover = sum(abs(e) <= 1.96 * s for e, (_v, s) in zip(errs, got))
                cells += [f"{sum(v for v, _s in got) / len(got):+.2f}", f"{math.sqrt(sum(e * e for e in errs) / len(errs)):.2f}",
                          f"{100 * cover / len(got):.0f} ({cover}/{len(got)})"]  # fmt: skip
            else:
                cells += ["-", "-", "-"]
        for key in ("gps_outlier", "gps_outlier_scale"):
            vals = sorted(f[key] for f in fits if f.get(key) is not None)
            cells.append(f"{vals[len(vals) // 2]:.3g}" if vals else "-")
        rows.append(cells)
    return header, rows


def markdown(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def row_label(rec: dict) -> str:
    """The study row a record belongs to: its condition, with the fit options it added."""
    if "[" in rec["condition"] or not rec.get("extra"):
        return rec["condition"]
    return f"{rec['condition']} [{' '.join(rec['extra'])}]"


def describe(label: str) -> str:
    cond = sc.CONDITIONS[label.split(" [")[0]]
    parts = [cond.walk, cond.error, *cond.junk]
    if cond.minutes != 60.0:
        parts.append(f"{cond.minutes / 60:g} h")
    if cond.attitude_deg != 2.0 and cond.error != "exact":
        parts.append(f"attitude {cond.attitude_deg:g} deg")
    return ", ".join(parts)


def report_records(runs=REPORT_RUNS, out: Path = OUT) -> dict[str, tuple[ReportRun, list[dict]]]:
    """Per study row, the newest run of it in ``runs`` and its records."""
    rows: dict[str, tuple[ReportRun, list[dict]]] = {}
    for run in runs:
        by: dict[str, list[dict]] = {}
        for line in (out / run.file).read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                by.setdefault(row_label(rec), []).append(rec)
        for label, recs in by.items():
            rows.pop(label, None)  # re-inserted: rows keep the order of their newest run
            rows[label] = (run, recs)
    return rows


def docs_block(rows: dict[str, tuple[ReportRun, list[dict]]]) -> str:
    """The docs' study section: the table of every row and what it says against the issue's
    targets, every figure computed here from the records."""
    header, cells = None, []
    n_conv = n_silent = 0
    order = list(sc.CONDITIONS)
    ordered = sorted(rows.items(), key=lambda item: (order.index(item[0].split(" [")[0]), item[0]))
    for label, (run, recs) in ordered:
        relabelled = [{**r, "condition": label} for r in recs]
        h, (row,) = table(relabelled)
        header = ["condition", "walk, pose error, junk", "fit code", "started (UTC)", *h[1:-1]]
        started = min(r.get("started", "?") for r in recs).removesuffix(" UTC")
        cells.append([label, describe(label), run.commit, started, *row[1:-1]])
        n_conv += sum(r.get("status") == "converged" for r in recs)
        n_silent += row[-2]
    short, off, unlikely = [], [], []
    for label, (_run, recs) in ordered:
        conv = [r for r in recs if r.get("status") == "converged"]
        if len(conv) < 0.99 * len(recs):
            short.append(label)
        for name in ("kappa_eq", "r_en"):
            k, n = covered(conv, name)
            if not n or 90 <= round(100 * k / n) <= 98:
                continue
            off.append(f"{label} ({name} {100 * k / n:.0f} %)")
            # outside the central 95 % of Binomial(n, 0.95): what exact intervals rarely give
            if not scipy.stats.binom.ppf(0.025, n, 0.95) <= k <= scipy.stats.binom.ppf(0.975, n, 0.95):
                unlikely.append(f"{label} ({name} {k}/{n})")
    # P(|z| > 3) for a standard normal z, two estimates per fit
    expected = n_conv * 2 * math.erfc(3 / math.sqrt(2))
    lines = [
        "Each row: the study's campaigns (`tests/perf/study_campaigns.py`: 60-minute 1 Hz walks",
        "with a hidden truth, written apart from the fit and from `tests/fit_campaign.py`) on the",
        f"first `runs` report seeds from {REPORT_SEED0:,} (the rules were developed on tuning seeds from 0 only),",
        "fitted by `arva-bench fit CSV --json` with its defaults and the options in brackets, by",
        "the fit code named (a row is replaced when its condition is run again). `silent`: converged,",
        "|z| > 3 for kappa_eq or r_en, and no warning note. `conv %` counts exit 0; `crash` a fit",
        "with no JSON (traceback or the study's 600 s limit). r_en's columns count the fits that report",
        "an r_en: a fit that says \"not determined\" has none (most near-only walks).",
        "",
        markdown(header, cells),
        "",
        f"Against the issue's targets: {n_conv} converged fits; conditions under 99 % converged:",
        f"{', '.join(short) if short else 'none'}. Coverage outside 90-98 %: {'; '.join(off) if off else 'none'};",
        "of these, outside what exact 95 % intervals give in 95 % of studies of that many fits:",
        f"{'; '.join(unlikely) if unlikely else 'none'}.",
        f"Silent misses: {n_silent}. With exact standard errors",
        f"|z| > 3 happens to 0.27 % of estimates, so {expected:.1f} would be expected over these",
        f"{n_conv} fits (two estimates each) by chance alone; 0 is a target no honest interval meets",
        "for sure, but more than that count says the intervals are too short.",
    ]
    return "\n".join(lines)


def write_docs(block: str, docs=DOCS) -> None:
    stamp = (
        f"_Table built {time.strftime('%Y-%m-%d', time.gmtime())} at commit {git_revision()} by "
        "`python tests/perf/calibration_study.py --docs` from the runs in its `REPORT_RUNS`._"
    )
    section = f"<!-- BEGIN study -->\n{block}\n\n{stamp}\n<!-- END study -->\n"
    for path in docs:
        replace_section(path, "study", section)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default=",".join(sc.CONDITIONS), help="comma-separated condition names")
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--skip", type=int, default=0, help="start this many seeds in (to continue an earlier run)")
    ap.add_argument("--tuning", action="store_true", help="development seeds (0 up) instead of the report seeds")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "tests/perf/out/calibration_study.jsonl")
    ap.add_argument("--extra", default="", help="extra fit options, space-separated")
    ap.add_argument(
        "--with", dest="variants", action="append", default=[], metavar="COND:OPTIONS",
        help="also run condition COND with these fit options (space-separated), as the row 'COND [OPTIONS]'",
    )
    ap.add_argument("--table", type=Path, help="only print the table of this jsonl")
    ap.add_argument("--docs", action="store_true", help="write the docs' study table from REPORT_RUNS (runs no fit)")
    args = ap.parse_args(argv)
    if args.docs:
        block = docs_block(report_records())
        print(block)
        write_docs(block)
        return 0
    if args.table:
        recs = [json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]
        print(markdown(*table(recs)))
        extras = extras_table(recs)
        if extras is not None:
            print()
            print(markdown(*extras))
        return 0
    names = [n for n in args.conditions.split(",") if n]
    unknown = [n for n in names if n not in sc.CONDITIONS]
    if unknown:
        ap.error(f"unknown condition(s): {', '.join(unknown)} (choose from {', '.join(sc.CONDITIONS)})")
    variants = []
    for item in args.variants:
        cname, sep, opts = item.partition(":")
        if not sep or cname not in sc.CONDITIONS or not opts.split():
            ap.error(f"--with {item!r}: expected COND:OPTIONS with a known condition and some options")
        variants.append((cname, opts.split()))
    seed0 = (0 if args.tuning else REPORT_SEED0) + args.skip
    extra = args.extra.split()
    jobs = [(sc.CONDITIONS[n], seed0 + k, extra, None) for k in range(args.seeds) for n in names]
    jobs += [
        (sc.CONDITIONS[c], seed0 + k, extra + opts, f"{c} [{' '.join(opts)}]") for k in range(args.seeds) for c, opts in variants
    ]
    jobs.sort(key=lambda job: job[1])  # seed by seed: every row grows together when a run is cut short
    args.out.parent.mkdir(parents=True, exist_ok=True)
    records = []
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    commit = git_revision()
    with tempfile.TemporaryDirectory() as tmp, open(args.out, "a") as fh, ThreadPoolExecutor(args.workers) as pool:
        for rec in pool.map(lambda job: run_one(job[0], job[1], job[2], Path(tmp), job[3]), jobs):
            rec["started"] = started
            rec["commit"] = commit
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            records.append(rec)
            f = rec.get("fit") or {}
            print(
                f"{rec['condition']:<16} seed {rec['seed']:>8} {rec['status']:<13} "
                f"kappa {f.get('kappa_eq') or float('nan'):.4f} (truth {rec['truth']['kappa_eq']:.4f}) "
                f"r_en {f.get('r_en') or float('nan'):.1f} (truth {rec['truth']['r_en']:.1f}) "
                f"{rec.get('wall', 0):.1f} s {'; '.join(rec.get('warnings', []))[:80]}",
                flush=True,
            )
    print()
    print(markdown(*table(records)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
