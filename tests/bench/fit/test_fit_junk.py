"""The junk real CSVs hold (issue 28, Build item 3): duplicated time stamps, repeated
slots and gaps are counted and fitted; stamps that go backwards and tables the fit
cannot use exit 2 with one line; no table is a traceback (hypothesis over junk CSVs)."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.cli import main
from bench.fit.likelihood import PoseTrack
from bench.fit.table import COLUMNS, FitInputError, Table, TimeStamps, check_times
from emulator.receiver.model import ModelParams
from fit_campaign import PoseError, emulate_campaign

TRUTH = ModelParams(kappa_eq=1.48, r_en=80.0)
ERROR = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0)


def run(capsys, *argv):
    code = main(["fit", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def rows(table: Table, idx) -> Table:
    """The rows ``idx`` (an index array: rows may repeat), in that order."""
    cols = {k: v[idx] for k, v in table.columns().items()}
    return Table.from_mapping(table.source, cols)


def stamps(t, seq, ids) -> TimeStamps:
    n = len(t)
    table = Table.from_columns(
        "x", t, seq, ids, np.full(n, 100), np.zeros(n), np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)),
        np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)),
    )  # fmt: skip
    return check_times(table)


def test_time_stamps_are_counted_per_epoch():
    # one epoch = consecutive rows with the same (t, seq): slots of two transmitters and
    # empty slots (id -1) share t without being duplicates
    assert stamps([0, 0, 0, 1, 1, 2], [0, 0, 0, 1, 1, 2], [1, 2, -1, 1, -1, 1]) == TimeStamps(3, 0, 0, 0, 1.0)
    # another epoch (seq 2) stamped like the one before it: a duplicated stamp
    assert stamps([0, 1, 1, 2], [0, 1, 2, 3], [1, 1, 1, 1]) == TimeStamps(4, 1, 0, 0, 1.0)
    # the same slot of one epoch twice (a line logged twice): repeated; id -1 never is
    assert stamps([0, 1, 1, 1, 1, 2], [0, 1, 1, 1, 1, 2], [1, 1, 1, -1, -1, 1]) == TimeStamps(3, 0, 1, 0, 1.0)
    # gaps: intervals over 3 times the median one (1 s); the largest is reported
    assert stamps([0, 1, 2, 3, 10, 11, 12, 40], range(8), [1] * 8) == TimeStamps(8, 0, 0, 2, 28.0)
    assert stamps([5.0], [0], [1]) == TimeStamps(1, 0, 0, 0, 0.0)


def test_stamps_that_go_backwards_name_the_line():
    table = emulate_campaign(0, TRUTH, seed=1, n_rows=80)
    table.t[40] = 38.5
    table.lines = np.arange(2, 82)
    with pytest.raises(FitInputError) as exc:
        check_times(table)
    assert str(exc.value) == "fit: " + table.source + ": line 42: t goes backwards (38.5 after 39.0)"


def test_a_time_stamp_beyond_any_clock_is_refused():
    table = emulate_campaign(0, TRUTH, seed=1, n_rows=80)
    table.t[70:] = 1e13
    with pytest.raises(FitInputError) as exc:
        check_times(table)
    assert str(exc.value) == "fit: " + table.source + ": row 70: t = 10000000000000.0 is beyond 1e+12 s"


def test_the_pose_track_keeps_one_sample_per_stamp():
    """A row stamped like the one before it shares that row's pose sample: the track is
    the one of the table without it (the IndexError of issue 28 was here)."""
    table = emulate_campaign(0, TRUTH, seed=2, n_rows=60)
    dup = rows(table, np.r_[0:31, 30, 31:60])  # row 30 again, with row 31's seq: same stamp
    dup.seq[31] = 999
    dup.rx_pos[31] += 5.0  # its own pose is not the track's sample
    plain, track = PoseTrack(table), PoseTrack(dup)
    assert np.array_equal(track.t, plain.t)
    for offset in (0.0, 0.37, -1.2):
        a, b = plain.geometry(offset), track.geometry(offset)
        keep = np.r_[0:31, 32:61]
        assert np.array_equal(b.log_r[keep], a.log_r) and np.array_equal(b.g[:, keep], a.g)
        assert b.log_r[31] == a.log_r[30]


def junk_campaign(tmp_path):
    """20 minutes at 1 Hz with consumer GPS error; one stamp duplicated (row 100 gets row
    99's t), a 31 s gap (rows 300-329 lost) and 2 % of the detected rows turned into
    spurious -1 rows."""
    table = emulate_campaign(20, TRUTH, seed=4, pose_error=ERROR)
    table.t[100] = table.t[99]
    table = rows(table, np.r_[0:300, 330:len(table)])
    rng = np.random.default_rng(7)
    detected = np.flatnonzero(table.d != -1)
    spurious = rng.choice(detected, int(0.02 * detected.size), replace=False)
    table.d[spurious], table.id[spurious], table.delta[spurious] = -1, -1, -1
    path = tmp_path / "junk.csv"
    table.write_csv(path)
    return path, table


@pytest.mark.slow
def test_duplicated_stamp_gap_and_spurious_minus_ones_fit(capsys, tmp_path):
    path, table = junk_campaign(tmp_path)
    code, out, err = run(capsys, path, "--json")
    assert (code, err) == (0, "")
    res = json.loads(out)
    assert res["converged"] is True and res["n_rows"] == 1170
    assert res["time_stamps"] == {"epochs": 1170, "duplicated": 1, "repeated": 0, "gaps": 1, "largest_gap_seconds": 31.0}
    # the goodness-of-fit check named the spurious -1 rows, so the fit took a dropout probability
    spurious = res["notes"][0]
    assert spurious.startswith(
        "spurious -1 rows: 9 rows say 'nothing heard' where the model gives that less than 0.1 % chance "
    ) and "; refitted with a dropout probability (as --fit dropout): " in spurious
    assert "dropout" in res["free"] and abs(res["dropout"] - 0.02) < 3 * res["dropout_se"]
    assert res["notes"][1] == (
        "time stamps: 1 epoch shared the stamp of the one before; 1 gap in the time stamps (the largest 31 s) "
        "(kept as readings; rows sharing a stamp share one pose in the time-offset track)"
    )
    assert abs(res["kappa_eq"] - TRUTH.kappa_eq) < 3 * res["kappa_eq_se"]
    assert abs(res["r_en"] - TRUTH.r_en) < 3 * res["r_en_se"]
    # what the clock-offset scan found (before the dropout refit replaced the fit) stays said
    assert [n[:29] for n in res["notes"] if n.startswith("time offset")] == ["time offset: none found (a sc"]
    code, out, _err = run(capsys, path)
    assert code == 0 and "note: time stamps: 1 epoch shared the stamp of the one before" in out


def test_backwards_stamp_exits_2_with_one_line(capsys, tmp_path):
    table = emulate_campaign(5, TRUTH, seed=3)
    table.t[150], table.t[151] = table.t[151], table.t[150]
    path = tmp_path / "back.csv"
    table.write_csv(path)
    assert run(capsys, path) == (2, "", f"arva-bench: fit: {path}: line 153: t goes backwards (150.0 after 151.0)\n")


def test_one_row_exits_2_with_one_line(capsys, tmp_path):
    path = tmp_path / "one.csv"
    emulate_campaign(0, TRUTH, seed=3, n_rows=1).write_csv(path)
    assert run(capsys, path) == (2, "", f"arva-bench: fit: {path}: only 1 row; the fit needs at least 50\n")


# -- junk CSVs never give a traceback --------------------------------------------------------

BASE = emulate_campaign(0, TRUTH, seed=6, n_rows=150, pose_error=ERROR)

_index = st.integers(0, 149)
JUNK = st.one_of(
    st.tuples(st.just("dup_t"), _index),
    st.tuples(st.just("repeat_row"), _index),
    st.tuples(st.just("gap"), _index, st.floats(0.0, 1e9)),
    st.tuples(st.just("swap"), _index),
    st.tuples(st.just("minus1"), _index, st.integers(1, 150)),
    st.tuples(st.just("truncate"), st.integers(0, 149)),
    st.tuples(st.just("const_pos"), st.booleans()),
    st.tuples(st.just("same_t"), st.floats(-1e12, 1e12)),
    st.tuples(st.just("at_tx"), _index, st.integers(1, 150)),
    st.tuples(st.just("cell"), _index, st.sampled_from(COLUMNS), st.sampled_from(["nan", "inf", "", "1e400", "-0", "x"])),
    st.tuples(st.just("far"), _index, st.integers(0, 5000)),
)


def apply(table: Table, junk) -> tuple[Table, dict[int, tuple[str, str]]]:
    n = len(table)
    cells: dict[int, tuple[str, str]] = {}
    kind, *a = junk
    if kind == "dup_t" and 0 < a[0] < n:
        table.t[a[0]] = table.t[a[0] - 1]
    elif kind == "repeat_row" and a[0] < n:
        table = rows(table, np.r_[0 : a[0] + 1, a[0] : n])
    elif kind == "gap" and a[0] < n:
        table.t[a[0] :] += a[1]
    elif kind == "swap" and a[0] + 1 < n:
        table.t[[a[0], a[0] + 1]] = table.t[[a[0] + 1, a[0]]]
    elif kind == "minus1":
        table.d[a[0] : a[0] + a[1]] = -1
        table.id[a[0] : a[0] + a[1]] = -1
    elif kind == "truncate":
        table = rows(table, np.arange(min(a[0], n)))
    elif kind == "const_pos":
        table.rx_pos[:] = table.rx_pos[0]
        if a[0]:
            table.rx_quat[:] = table.rx_quat[0]
    elif kind == "same_t":
        table.t[:] = a[0]
    elif kind == "at_tx":
        table.rx_pos[a[0] : a[0] + a[1]] = table.tx_pos[a[0] : a[0] + a[1]]
    elif kind == "cell" and a[0] < n:
        cells[a[0]] = (a[1], a[2])
    elif kind == "far" and a[0] < n:
        table.d[a[0]] = a[1]
        table.id[a[0]] = 1
    return table, cells


def write(table: Table, cells, path) -> None:
    table.write_csv(path)
    if not cells:
        return
    lines = path.read_text().splitlines()
    for row, (col, text) in cells.items():
        if row + 1 >= len(lines):
            continue  # (the row was cut off after the cell was chosen)
        parts = lines[row + 1].split(",")
        parts[COLUMNS.index(col)] = text
        lines[row + 1] = ",".join(parts)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.slow
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(junk=st.lists(JUNK, min_size=1, max_size=3), exact=st.booleans())
def test_junk_csvs_fit_or_exit_2_with_one_line(junk, exact, capsys, tmp_path):
    table = rows(BASE, np.arange(len(BASE)))
    cells: dict = {}
    for j in junk:
        table, more = apply(table, j)
        cells.update(more)
    path = tmp_path / "junk.csv"
    write(table, cells, path)
    argv = [path, "--json"] + (["--gps-sigma", "0", "--attitude-sigma", "0"] if exact else [])
    code, out, err = run(capsys, *argv)
    if code == 2:
        assert out == "" and err.startswith(f"arva-bench: fit: ") and err.count("\n") == 1, err
        return
    res = json.loads(out)  # finite numbers only (no NaN: json.dumps(allow_nan=False))
    assert res["converged"] is (code == 0)
    assert err == ("" if code == 0 else f"arva-bench: fit: did not converge: {res['message']}\n")
