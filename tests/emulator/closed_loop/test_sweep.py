"""Search sweeps: seeded burials, a reproducible summary, the same rows in process, on a
process pool and on a Dask LocalCluster; the table and the command line."""

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from emulator.closed_loop.sweep import COLUMNS, SweepConfig, burial, summarize, summary_table, sweep, write_table

CONFIG = SweepConfig(n=4, seed=3, t_max=900.0, chunk=2)


def same(a, b):
    """Rows equal, NaN equal to NaN (after pickling, NaNs are different objects)."""
    norm = lambda rows: [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in r.items()} for r in rows]  # noqa: E731
    return norm(a) == norm(b)


@pytest.fixture(scope="module")
def local():
    return sweep(CONFIG, workers=1)


def test_burials_are_seeded_and_in_range():
    cfg = SweepConfig(n=200, seed=9)
    all_tx = [burial(cfg, i) for i in range(200)]
    assert burial(cfg, 17) == all_tx[17] and burial(cfg, 17) != all_tx[18]
    assert {len(b) for b in all_tx} == {1, 2, 3, 4}
    for txs in all_tx:
        for tx in txs:
            x, y, z = tx["position"]
            assert 0 <= x <= 80 and 0 <= y <= 80 and -2.5 <= z <= -0.3 and z == -tx["depth"]
            assert np.linalg.norm(tx["orientation"]) == pytest.approx(1.0)
    # Orientations are uniform: the dipole's vertical component averages ~0, |.| ~ 1/2.
    w, x, y, z = np.array([tx["orientation"] for txs in all_tx for tx in txs]).T
    mz = 2 * (x * z - w * y)
    assert abs(mz.mean()) < 0.1 and abs(np.abs(mz).mean() - 0.5) < 0.06


@pytest.mark.slow
@pytest.mark.timing  # the speed-up over real time
def test_small_sweep_summary_is_exact(local):
    assert [len(local.rows), local.scene_s] == [39, 5977.0]  # 3 strategies x 13 transmitters
    s = {row["strategy"]: row for row in local.summary}
    assert [s[k]["located"] for k in ("flux", "flux_reverse", "receiver_only")] == [10 / 13, 1.0, 1.0]
    assert s["flux"]["t_locate_median_s"] == 225.0
    assert s["flux_reverse"]["t_all_median_s"] == 306.5
    assert s["receiver_only"]["t_locate_median_s"] == pytest.approx(301.6, abs=1e-9)
    assert s["receiver_only"]["error_median_m"] == pytest.approx(0.268744, abs=1e-6)
    assert s["flux"]["error_max_m"] == pytest.approx(6.711078, abs=1e-6)
    # The sweep ran faster than real time, by a wide margin.
    assert local.speedup > 200


@pytest.mark.slow
def test_rerun_gives_the_same_summary(local):
    again = sweep(CONFIG, workers=1)
    assert same(again.rows, local.rows) and same(again.summary, local.summary)


@pytest.mark.slow
@pytest.mark.subprocess
def test_process_pool_gives_the_same_rows(local):
    pooled = sweep(CONFIG, workers=2)
    assert pooled.executor == "process pool x2"
    assert same(pooled.rows, local.rows)


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(180)
def test_dask_local_cluster_gives_the_same_rows(local):
    """Worker processes, as on a real cluster: the config and the chunks are pickled to
    them and the package is imported there."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        result = sweep(CONFIG, scheduler=cluster.scheduler_address)
    assert result.executor == f"dask {cluster.scheduler_address}"
    assert same(result.rows, local.rows) and same(result.summary, local.summary)


def test_table_round_trips(local, tmp_path):
    path = tmp_path / "rows.csv"
    write_table(local.rows, path)
    with path.open() as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == COLUMNS and len(rows) == len(local.rows)
    missed = [r for r in rows if r["found"] == "False"]
    assert missed and all(r["t_found_s"] == "" and r["error_m"] == "" for r in missed)
    first = local.rows[0]
    assert float(rows[0]["tx_x"]) == pytest.approx(first["tx_x"], abs=1e-6)


def test_summary_of_nothing_found():
    rows = [{"strategy": "s", "v_max": 1.0, "k_c": 0.2, "burial": 0, "found": False, "t_found_s": math.nan,
             "error_m": math.nan, "all_found": False, "t_all_s": math.nan}]
    (s,) = summarize(rows)
    assert s["located"] == 0.0 and math.isnan(s["t_locate_median_s"]) and math.isnan(s["error_max_m"])
    assert "| s | 1 | 0.2 | 1 | 1 | 0.0 % |" in summary_table([s])


@pytest.mark.subprocess
def test_command_line(tmp_path):
    out = tmp_path / "sweep.csv"
    proc = subprocess.run(
        [sys.executable, "-m", "emulator.closed_loop.sweep", "--n", "2", "--seed", "3", "--strategies", "receiver_only",
         "--workers", "1", "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("| strategy | v_max | k_c |")
    assert "| receiver_only | 1 | 0.2 | 2 |" in proc.stdout
    assert "x real time, in process)" in proc.stderr
    assert out.read_text().splitlines()[0] == ",".join(COLUMNS)
    bad = subprocess.run([sys.executable, "-m", "emulator.closed_loop.sweep", "--strategies", "magic"], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and "unknown strategy 'magic'" in bad.stderr


def test_parquet_table_has_the_csv_columns_and_values(local, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    path = tmp_path / "rows.parquet"
    write_table(local.rows, path)
    table = pq.read_table(path)
    assert tuple(table.column_names) == COLUMNS
    assert same(table.to_pylist(), [{k: r[k] for k in COLUMNS} for r in local.rows])


@pytest.mark.subprocess
def test_bad_output_is_refused_before_the_sweep_runs(tmp_path):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "emulator.closed_loop.sweep", "--n", "1000000", *args],
                              capture_output=True, text=True, timeout=60)  # fmt: skip

    for out, why in [
        (tmp_path / "rows.xlsx", f"arva-sweep: error: argument --out: {tmp_path / 'rows.xlsx'}: expected a .csv or .parquet file\n"),
        (tmp_path / "no" / "rows.csv", f"arva-sweep: error: argument --out: {tmp_path / 'no' / 'rows.csv'}: directory {tmp_path / 'no'} does not exist\n"),
        (Path("/proc/rows.csv"), "arva-sweep: --out /proc/rows.csv: cannot write: No such file or directory\n"),
    ]:  # fmt: skip
        p = run("--out", str(out))
        assert (p.returncode, p.stdout, p.stderr) == (2, "", why)
    from without_extra import run_without

    p = run_without("pyarrow", "emulator.closed_loop.sweep:main", ["--n", "1000000", "--out", str(tmp_path / "rows.parquet")])
    assert (p.returncode, p.stdout) == (2, "")
    assert p.stderr == "arva-sweep: Parquet output needs pyarrow (install the extra: pip install 'arva-bench[parquet]')\n"
    p = run_without("distributed", "emulator.closed_loop.sweep:main", ["--n", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert (p.returncode, p.stdout) == (2, "")
    assert p.stderr == (
        "arva-sweep: --scheduler (a dask cluster) needs dask.distributed (install the extra: pip install 'arva-bench[cluster]')\n"
    )


def test_tail_statistics_and_their_bootstrap_intervals():
    from emulator.closed_loop.sweep import bootstrap_tail

    burial_of = np.repeat(np.arange(500), 2)  # 500 burials, 2 located transmitters each
    values = np.arange(1000, dtype=np.float64)  # 0 .. 999
    a = bootstrap_tail(burial_of, values, 500, 400, seed=4)
    assert a == bootstrap_tail(burial_of, values, 500, 400, seed=4)  # seeded
    assert a != bootstrap_tail(burial_of, values, 500, 400, seed=5)
    lo, hi = a["p99"]
    assert lo < np.quantile(values, 0.99) < hi and 950 < lo and hi <= 999
    assert a["max"][1] == 999.0 and a["max"][0] >= 990  # never above the sample maximum
    # Burials without a located transmitter still count in the resampling.
    b = bootstrap_tail(np.array([0]), np.array([7.0]), 20, 200, seed=1)
    assert b["p99"] == b["max"] == (7.0, 7.0)
    assert bootstrap_tail(np.array([], dtype=np.int64), np.array([]), 5, 100, 0)["p99"][0] != 0.0  # NaN


def test_summary_has_tails(local):
    s = {row["strategy"]: row for row in local.summary}["receiver_only"]
    found = [r for r in local.rows if r["strategy"] == "receiver_only" and r["found"]]
    assert s["t_locate_max_s"] == max(r["t_found_s"] for r in found)
    assert s["t_locate_p99_s"] == pytest.approx(np.quantile([r["t_found_s"] for r in found], 0.99), abs=0)
    assert s["error_max_m"] == max(r["error_m"] for r in found)
    lo, hi = s["error_p99_ci_m"]
    assert lo <= hi <= s["error_max_m"]
    assert "| t locate p99 [95 % CI] / max [s] | error p99 [95 % CI] [m] |" in summary_table(local.summary)


@pytest.mark.slow
@pytest.mark.subprocess
def test_command_line_engines_give_the_same_table():
    def run(*args):
        return subprocess.run([sys.executable, "-m", "emulator.closed_loop.sweep", "--n", "2", "--seed", "4",
                               "--strategies", "flux_reverse", "--workers", "1", "--bootstrap", "50", *args],
                              capture_output=True, text=True, timeout=120)  # fmt: skip

    a, b = run(), run("--engine", "run")
    assert a.returncode == b.returncode == 0, a.stderr + b.stderr
    assert a.stdout == b.stdout and "| flux_reverse | 1 | 0.2 | 2 |" in a.stdout
    bad = run("--engine", "fast")
    assert bad.returncode == 2 and "invalid choice: 'fast'" in bad.stderr
