"""The fit's CSV reader: exact one-line errors naming file, line and column; never a
crash on arbitrary text (hypothesis)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.fit.csvio import parse_csv, read_csv
from bench.fit.table import COLUMNS, FitInputError, Table
from firmware_proto.errors import InputError

HEADER = ",".join(COLUMNS)
ROW = "0.0,0,1,1905,21,20.0,5.0,1.0,1.0,0.0,0.0,0.0,0.0,0.0,-1.0,1.0,0.0,0.0,0.0"
CENSORED = "1.0,1,-1,-1,-1,70.0,5.0,1.0,1.0,0.0,0.0,0.0,0.0,0.0,-1.0,1.0,0.0,0.0,0.0"


def csv(*rows: str, header: str = HEADER) -> str:
    return "\n".join([header, *rows]) + "\n"


def with_cell(column: str, value: str) -> str:
    cells = ROW.split(",")
    cells[COLUMNS.index(column)] = value
    return ",".join(cells)


def test_reads_columns_exactly():
    t = parse_csv(csv(ROW, CENSORED), "walk.csv")
    assert len(t) == 2 and t.source == "walk.csv"
    assert t.d.tolist() == [1905, -1] and t.id.tolist() == [1, -1] and t.delta.tolist() == [21, -1]
    assert t.rx_pos.tolist() == [[20.0, 5.0, 1.0], [70.0, 5.0, 1.0]]
    assert t.tx_pos[1].tolist() == [0.0, 0.0, -1.0] and t.rx_quat[0].tolist() == [1.0, 0.0, 0.0, 0.0]
    assert t.lines.tolist() == [2, 3]


def test_column_order_extra_columns_crlf_bom_and_blank_lines():
    cols = list(COLUMNS)[::-1] + ["note"]
    cells = ROW.split(",")[::-1] + ["x"]
    text = "\ufeff" + ",".join(cols) + "\r\n\r\n" + ",".join(cells) + "\r\n"
    t = parse_csv(text.encode(), "r.csv")
    assert t.d.tolist() == [1905] and t.rx_pos.tolist() == [[20.0, 5.0, 1.0]] and t.lines.tolist() == [3]


def test_integral_floats_accepted_in_integer_columns():
    assert parse_csv(csv(with_cell("d", "1905.0")), "f").d.tolist() == [1905]


def test_round_trip_through_write_csv(tmp_path):
    rng = np.random.default_rng(1)
    n = 7
    t = Table.from_columns(
        "x", rng.random(n) * 100, np.arange(n), np.r_[1, 1, -1, 1, 1, -1, 1], np.r_[0, 12, -1, 300, 5000, -1, 4999],
        np.r_[0, -89, -1, 5, 89, -1, 0], rng.normal(size=(n, 3)) * 50, rng.normal(size=(n, 4)),
        rng.normal(size=(n, 3)), rng.normal(size=(n, 4)),
    )  # fmt: skip
    t.write_csv(tmp_path / "t.csv")
    back = read_csv(tmp_path / "t.csv")
    for name, col in t.columns().items():
        assert np.array_equal(back.columns()[name], col), name


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "fit: w.csv: empty file (no header)"),
        ("\n\n", "fit: w.csv: empty file (no header)"),
        (HEADER + "\n", "fit: w.csv: no data rows"),
        (csv(ROW, header=HEADER.replace("rx_qw,", "")), "fit: w.csv: missing column rx_qw"),
        (csv(ROW, header="t,seq,id,d"), "fit: w.csv: missing columns delta, rx_x, rx_y, rx_z, rx_qw, rx_qx, rx_qy, rx_qz, "
         "tx_x, tx_y, tx_z, tx_qw, tx_qx, tx_qy, tx_qz"),
        (csv(ROW, header=HEADER + ",d"), "fit: w.csv: line 1: duplicate column d"),
        (csv(ROW, "1,2,3"), "fit: w.csv: line 3: expected 19 fields, got 3"),
        (csv(ROW, with_cell("rx_y", "abc")), "fit: w.csv: line 3: column rx_y: not a number: 'abc'"),
        (csv(with_cell("rx_y", "")), "fit: w.csv: line 2: column rx_y: not a number: ''"),
        (csv(with_cell("t", "1_000")), "fit: w.csv: line 2: column t: not a number: '1_000'"),
        (csv(ROW, ROW, with_cell("rx_x", "nan")), "fit: w.csv: line 4: column rx_x: not finite: 'nan'"),
        (csv(with_cell("tx_qz", "-inf")), "fit: w.csv: line 2: column tx_qz: not finite: '-inf'"),
        (csv(with_cell("tx_z", "1e999")), "fit: w.csv: line 2: column tx_z: not finite: '1e999'"),
        (csv(ROW, with_cell("d", "12.5")), "fit: w.csv: line 3: column d: not an integer: '12.5'"),
        (csv(with_cell("seq", "1e30")), "fit: w.csv: line 2: column seq: not an integer: '1e30'"),
        (csv(with_cell("d", "-2")), "fit: w.csv: line 2: column d: must be -1 or >= 0 cm, got -2"),
        (
            csv(ROW, ",".join(ROW.split(",")[:8] + ["0", "0", "0", "1e-10"] + ROW.split(",")[12:])),
            "fit: w.csv: line 3: rx_qw..rx_qz: quaternion norm 1e-10 is below 1e-09",
        ),
        (csv(with_cell("rx_x", "2e9")), "fit: w.csv: line 2: rx_x..rx_z: coordinate beyond 1e+09 m"),
        (csv('"unterminated'), "fit: w.csv: line 2: malformed CSV: unexpected end of data"),
    ],
)
def test_exact_errors(text, message):
    with pytest.raises(FitInputError) as err:
        parse_csv(text, "w.csv")
    assert str(err.value) == message


def test_bytes_that_are_not_utf8():
    with pytest.raises(FitInputError, match=r"^fit: b.csv: not UTF-8 text \(byte 3\)$"):
        parse_csv(b"t,s\xff\n", "b.csv")


def test_file_errors(tmp_path):
    with pytest.raises(FitInputError) as err:
        read_csv(tmp_path / "missing.csv")
    assert str(err.value) == f"fit: {tmp_path / 'missing.csv'}: cannot read: No such file or directory"
    with pytest.raises(FitInputError) as err:
        read_csv(tmp_path)
    assert str(err.value) == f"fit: {tmp_path}: is a directory, not a CSV file"


cell = st.one_of(
    st.sampled_from(["0", "1", "-1", "1905", "0.5", "nan", "inf", "", "1e400", "x", '"q"', "1_0", "-0", " 2 "]),
    st.text(max_size=6),
)


@settings(max_examples=300)
@given(st.text(max_size=400))
def test_arbitrary_text_only_raises_input_errors(text):
    try:
        parse_csv(text, "fuzz.csv")
    except InputError as exc:
        assert str(exc).startswith("fit: fuzz.csv: ") and "\n" not in str(exc)


@pytest.mark.slow
@settings(max_examples=300)
@given(st.lists(st.lists(cell, min_size=17, max_size=21), min_size=1, max_size=4), st.booleans())
def test_near_valid_rows_only_raise_input_errors(rows, crlf):
    sep = "\r\n" if crlf else "\n"
    text = HEADER + sep + sep.join(",".join(r) for r in rows) + sep
    try:
        t = parse_csv(text.encode("utf-8", "surrogatepass"), "fuzz.csv")
    except InputError as exc:
        assert str(exc).startswith("fit: fuzz.csv: ") and "\n" not in str(exc)
    else:
        assert len(t) == len(rows) and np.all(np.isfinite(t.rx_pos)) and np.all(t.d >= -1)
