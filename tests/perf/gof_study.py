"""False alarms and detections of the fit's goodness-of-fit check (issue 28, Build item 5):
``arva-bench fit CSV --json`` on independent campaigns (``study_campaigns.py``, through
``calibration_study.run_one``), some the fit's model describes (well specified), some it
does not (heavy-tailed GPS error, spurious "nothing heard" rows).

A run "fires" when the fit converged and its ``goodness_of_fit.fits`` is false (the note
that names the misfit is then among the notes). The table per condition: runs, converged,
fired, and the fired fraction with a 95 % Wilson interval: false alarms on the well
specified conditions, detections on the others; and calibration_study's silent misses
(converged, |z| > 3, no warning note) with the check's note and, in parentheses, without
it. ``--write-doc`` puts the table, with the
date, machine and load, into docs/calibration.md between its ``gof`` markers.

Seeds: ``--tuning`` from 0 (for choosing thresholds); without it from
``calibration_study.REPORT_SEED0`` (the numbers that go into the docs).

Usage::

    python tests/perf/gof_study.py --well 6 --misfit 12 --workers 1 [--tuning] [--out F.jsonl]
    python tests/perf/gof_study.py --table F.jsonl [--write-doc]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import calibration_study as cs  # noqa: E402
from _report import machine  # noqa: E402
import study_campaigns as sc  # noqa: E402

ROOT = cs.ROOT
#: Conditions the fit's model describes: no warning of misfit should appear (the first
#: four the issue's; the other walk shapes of study_campaigns.py with the same error).
WELL = ("radial-gm", "level-gm", "radial-exact", "level-exact", "spiral-gm", "near-gm", "far-gm", "drone-gm")
#: Conditions it does not describe, and the check should say so.
MISFIT = {
    "level-heavy": sc.CONDITIONS["level-heavy"],
    "level-student": sc.CONDITIONS["level-student"],
    "level-gm-spurious": sc.Condition("level-gm-spurious", "level_rw", "gm", ("spurious",)),
    "radial-gm-spurious": sc.Condition("radial-gm-spurious", "radial", "gm", ("spurious",)),
}
DOC = ROOT / "docs/calibration.md"
BEGIN, END = "<!-- BEGIN gof -->", "<!-- END gof -->"


def fired(rec: dict) -> bool | None:
    """True when the check says the model does not fit; None when the fit did not converge."""
    if rec.get("status") != "converged":
        return None
    gof = (rec.get("fit") or {}).get("goodness_of_fit")
    return gof is not None and gof.get("fits") is False


#: What the misfit note blames, by its words (bench/fit/diagnostics.py: GoodnessOfFit.note).
BLAME = (
    ("say 'nothing heard'", "spurious -1 rows"),
    ("central half", "heavy-tailed GPS (center)"),
    ("scatter more", "more scatter"),
    ("than it predicts", "shift"),
)


def blame(notes: list[str]) -> str:
    for note in notes:
        if "does not describe this walk" in note:
            return next((label for words, label in BLAME if words in note), "other")
    return "no note"


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


MISFIT_NOTE = "does not describe this walk"


def silent_misses(records: list[dict], with_note: bool = True) -> dict[str, int]:
    """calibration_study's silent misses (converged, |z| > 3 for kappa_eq or r_en, no warning
    note) per condition, counting the check's note as a warning or not."""
    if not with_note:
        records = [{**r, "warnings": [w for w in r.get("warnings", []) if MISFIT_NOTE not in w]} for r in records]
    header, rows = cs.table(records)
    name, silent = header.index("condition"), header.index("silent")
    return {row[name]: int(row[silent]) for row in rows}


def table(records: list[dict]) -> str:
    by: dict[str, list[dict]] = {}
    for r in records:
        by.setdefault(r["condition"], []).append(r)
    silent, silent_without = silent_misses(records), silent_misses(records, with_note=False)
    out = [
        "| condition | model | runs | converged | fired | fired % (95 % interval) | what the note blamed "
        "| silent misses (without the note) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    totals = {"well specified": [0, 0], "misspecified": [0, 0]}
    for name in sorted(by, key=lambda n: (n not in WELL, n)):
        recs = by[name]
        kind = "well specified" if name in WELL else "misspecified"
        conv = [r for r in recs if fired(r) is not None]
        hits = [r for r in conv if fired(r)]
        totals[kind][0] += len(hits)
        totals[kind][1] += len(conv)
        lo, hi = wilson(len(hits), len(conv))
        blamed: dict[str, int] = {}
        for r in hits:
            what = blame(r.get("notes", []))
            blamed[what] = blamed.get(what, 0) + 1
        pct = f"{100 * len(hits) / len(conv):.0f} ({100 * lo:.0f}-{100 * hi:.0f})" if conv else "-"
        out.append(
            f"| {name} | {kind} | {len(recs)} | {len(conv)} | {len(hits)} | {pct} | "
            + (", ".join(f"{k} {v}" for k, v in sorted(blamed.items())) or "-")
            + f" | {silent.get(name, 0)} ({silent_without.get(name, 0)}) |"
        )
    for kind, (k, n) in totals.items():
        if n:
            lo, hi = wilson(k, n)
            out.append(f"| **all {kind}** | | | {n} | {k} | {100 * k / n:.0f} ({100 * lo:.0f}-{100 * hi:.0f}) | | |")
    return "\n".join(out)


def write_doc(text: str) -> None:
    doc = DOC.read_text()
    a, b = doc.index(BEGIN) + len(BEGIN), doc.index(END)
    DOC.write_text(doc[:a] + "\n" + text + "\n" + doc[b:])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--well", type=int, default=6, help="seeds per well-specified condition")
    ap.add_argument("--misfit", type=int, default=12, help="seeds per misspecified condition")
    ap.add_argument("--conditions", default="", help="only these (comma-separated)")
    ap.add_argument("--tuning", action="store_true", help="development seeds (0 up) instead of the report seeds")
    ap.add_argument("--first", type=int, default=0, help="skip this many seeds")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "tests/perf/out/gof_study.jsonl")
    ap.add_argument("--table", type=Path, help="only print the table of this jsonl")
    ap.add_argument("--write-doc", action="store_true", help="write the table into docs/calibration.md")
    args = ap.parse_args(argv)
    if args.table:
        recs = [json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]
        text = table(recs)
        print(text)
        if args.write_doc:
            started = sorted({r.get("started", "?") for r in recs})
            seeds = sorted({r["seed"] for r in recs})
            text += (
                f"\n\n_Measured by `python tests/perf/gof_study.py` (seeds {seeds[0]}-{seeds[-1]}, "
                f"runs started {', '.join(started)}), {machine()}, load average {os.getloadavg()[0]:.1f} when the "
                "table was written (the machine was shared with other jobs)._"
            )
            write_doc(text)
        return 0
    conds = {**{n: sc.CONDITIONS[n] for n in WELL}, **MISFIT}
    names = [n for n in (args.conditions.split(",") if args.conditions else conds) if n]
    unknown = [n for n in names if n not in conds]
    if unknown:
        ap.error(f"unknown condition(s): {', '.join(unknown)} (choose from {', '.join(conds)})")
    seed0 = (0 if args.tuning else cs.REPORT_SEED0) + args.first
    jobs = [(conds[n], seed0 + k) for k in range(max(args.well, args.misfit)) for n in names
            if k < (args.well if n in WELL else args.misfit)]  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    records = []
    from concurrent.futures import ThreadPoolExecutor

    with tempfile.TemporaryDirectory() as tmp, open(args.out, "a") as fh, ThreadPoolExecutor(args.workers) as pool:
        for rec in pool.map(lambda job: cs.run_one(job[0], job[1], [], Path(tmp)), jobs):
            rec["started"] = started
            rec["load"] = os.getloadavg()[0]
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            records.append(rec)
            gof = (rec.get("fit") or {}).get("goodness_of_fit") or {}
            print(f"{rec['condition']:<20} seed {rec['seed']:>8} {rec['status']:<13} p {gof.get('p_value')} "
                  f"fired {fired(rec)} {rec.get('wall', 0):.1f} s", flush=True)  # fmt: skip
    print()
    print(table(records))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
