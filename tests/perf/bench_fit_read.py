"""Reading and fitting 10^5 rows with exact poses (issue 20). Prints a table and writes
docs/performance.md (section ``fit_read``).

Usage: python tests/perf/bench_fit_read.py [--rows N] [--rounds R] [--no-write]

An emulated campaign (``tests/fit_campaign.py``, kappa_eq = 1.542, r_en = 80 m, exact poses)
written as the normative CSV, then: ``read_csv`` (its one-pass numeric route, with pyarrow's
CSV reader when installed and with np.loadtxt, and the general csv-module route it falls
back to), and ``fit_table`` on the table read. Times
are best of R, on CPU time (the process's, all threads) and on the wall clock: on a host
shared with other jobs the wall clock measures the load as much as the code.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE.parent))  # tests/: the campaign generator

from _report import markdown_table, publish  # noqa: E402

from bench.fit import csvio  # noqa: E402
from bench_fit import counted_fit, eval_cost  # noqa: E402
from fit_campaign import emulate_campaign  # noqa: E402
from bench.fit import parallel as fit_module  # noqa: E402
from bench.fit import fit_table  # noqa: E402
from bench.fit.parallel import STENCIL_THREADS  # noqa: E402
from bench.fit.stages import SUBSAMPLE  # noqa: E402
from emulator.receiver.model import ModelParams  # noqa: E402


def timed(fn, rounds: int):
    """(result, best CPU seconds, best wall seconds)."""
    best_cpu = best_wall = float("inf")
    result = None
    for _ in range(rounds):
        c0, w0 = time.process_time(), time.perf_counter()
        result = fn()
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - w0)
    return result, best_cpu, best_wall


def one_thread_fit(table):
    """fit_table with everything on the calling thread (no stencil or row threads)."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(fit_module, "STENCIL_THREADS", 1)
        return fit_table(table)


def numpy_read(path: Path):
    """The one-pass route with numpy's parser (as without pyarrow installed)."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(csvio, "_arrow_columns", lambda _data, _width: None)
        return csvio.read_csv(path)


def general_read(path: Path):
    with pytest.MonkeyPatch.context() as m:
        m.setattr(csvio, "_parse_simple", lambda _text, _source: None)
        return csvio.read_csv(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "campaign.csv"
        emulate_campaign(0, ModelParams(kappa_eq=1.542, r_en=80.0), seed=1000, n_rows=args.rows).write_csv(path)
        size_mb = path.stat().st_size / 1e6
        table, read_cpu, read_wall = timed(lambda: csvio.read_csv(path), args.rounds)
        _, np_cpu, np_wall = timed(lambda: numpy_read(path), args.rounds)
        _, gen_cpu, gen_wall = timed(lambda: general_read(path), args.rounds)
        res, fit_cpu, fit_wall = timed(lambda: fit_table(table), args.rounds)
        _, one_cpu, one_wall = timed(lambda: one_thread_fit(table), args.rounds)
        _res, n_val, n_gsub, n_gall = counted_fit(table)
        c_val, c_gsub = eval_cost(table, res, SUBSAMPLE), eval_cost(table, res, SUBSAMPLE, grad=True)
        c_gall = eval_cost(table, res, grad=True)
        # The read's floor: the C number parser it uses alone over the same cells (pyarrow's
        # CSV reader when installed, else numpy's).
        raw = path.read_bytes()
        head, _, body = raw.partition(b"\n")
        width = head.count(b",") + 1
        arrow = csvio._arrow_columns(raw, width) is not None
        parse = (
            (lambda: csvio._arrow_columns(raw, width))
            if arrow
            else (lambda: np.loadtxt(io.BytesIO(body), dtype=np.float64, delimiter=",", comments=None, encoding="latin1"))
        )
        _, parse_cpu, _ = timed(parse, args.rounds)
    load1 = os.getloadavg()[0]
    limit = n_val * c_val + n_gsub * c_gsub + n_gall * c_gall
    rows = [
        [f"`read_csv`, one-pass numeric route ({size_mb:.0f} MB{', pyarrow' if arrow else ''})", f"{read_cpu:.2f} s", f"{read_wall:.2f} s"],
        ["`read_csv`, one-pass route with `np.loadtxt` (no pyarrow)", f"{np_cpu:.2f} s", f"{np_wall:.2f} s"],
        ["`read_csv`, general csv-module route (before issue 20)", f"{gen_cpu:.2f} s", f"{gen_wall:.2f} s"],
        [f"`fit_table`, exact poses ({STENCIL_THREADS} threads)", f"{fit_cpu:.2f} s", f"{fit_wall:.2f} s"],
        ["`fit_table`, exact poses, one thread", f"{one_cpu:.2f} s", f"{one_wall:.2f} s"],
        ["**read + fit**", f"**{read_cpu + fit_cpu:.2f} s**", f"**{read_wall + fit_wall:.2f} s**"],
    ]
    if arrow:  # what an installation without the parquet extra gets
        rows.append(["read with `np.loadtxt` (no pyarrow) + fit", f"{np_cpu + fit_cpu:.2f} s", f"{np_wall + fit_wall:.2f} s"])
    table_md = markdown_table([f"{args.rows:,} rows", "CPU (best of " f"{args.rounds})", "wall"], rows)
    est = res.estimate
    body = (
        f"{table_md}\n\nLoad average {load0:.1f} before, {load1:.1f} after (2 cores; above ~1 other jobs shared "
        f"them and the wall clock shows it). Target (issue 20): read + fit <= 1 s. Estimates: kappa_eq = "
        f"{est['kappa_eq']:.5f}, r_en = {est['r_en']:.2f} m. The fit's CPU time counts all its threads "
        "(two evaluate the points of each Hessian's stencil and of the pilot's grid, and a single pass runs "
        "its two halves on two threads: with a second core free the wall time is below the CPU time; the "
        "one-thread row is the same fit with `STENCIL_THREADS = 1`, the same estimates, to show what the threads "
        "buy on the day's machine). "
        "Its machine limit is its likelihood passes times their CPU cost at the estimate: "
        f"{n_val} value passes of the pilot's r_en grid on the {SUBSAMPLE:,}-row subsample x {1e3 * c_val:.1f} ms "
        f"+ {n_gsub} gradient passes there (log P and its derivatives in kappa_eq, r_en, pose_sigma in one pass) "
        f"x {1e3 * c_gsub:.1f} ms + {n_gall} gradient passes on all rows x {1e3 * c_gall:.1f} ms = {limit:.2f} s; "
        "of the all-rows passes, 3 are the Hessian by differences of the gradient (central in "
        "r_en, forward in kappa_eq, whose curvature is smooth; pose_sigma sits at its floor), the others BFGS "
        "steps from the subsample's Hessian to a "
        "decrement of 1e-3 nats (the curvature in r_en wavers by ~15 % over one standard error, so the "
        "subsample's estimate, ~2 standard errors away, takes 1-3 steps); the Hessian is taken there, and one "
        "Newton step with it, not evaluated, ends the fit. "
        + (
            "The read is pyarrow's C CSV reader over every cell (the `parquet` extra; without it numpy's "
            "slower `np.loadtxt` from bytes) "
            if arrow
            else "The read is numpy's C parser over every cell (`np.loadtxt` from bytes; with pyarrow installed, "
            "its faster CSV reader) "
        )
        + f"plus the checks; that parser alone takes {parse_cpu:.2f} s of CPU here, the floor of "
        f"this route ({parse_cpu / read_cpu:.0%} of the read)."
    )
    publish("fit_read", "Reading and fitting 10^5 rows", body, "python tests/perf/bench_fit_read.py", write=not args.no_write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
