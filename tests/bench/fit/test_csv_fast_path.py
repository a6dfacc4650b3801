"""The fit CSV reader's one-pass numeric parse (issue 20) gives exactly the Table, or the
error, of the general csv-module reader: it is only a faster route, never a different one."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.fit import csvio
from bench.fit.table import COLUMNS, FitInputError

HEADER = ",".join(COLUMNS)
ROW = "0.0,0,1,1905,21,20.0,5.0,1.0,1.0,0.0,0.0,0.0,0.0,0.0,-1.0,1.0,0.0,0.0,0.0"


def general(text: str):
    """The general reader alone (the fast route switched off for this call)."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(csvio, "_parse_simple", lambda _text, _source: None)
        return outcome(text)


def outcome(text: str):
    try:
        return csvio.parse_csv(text, "f.csv")
    except FitInputError as exc:
        return str(exc)


def same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            if not (x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f")):  # an empty HDOP is NaN
                return False
        elif x != y:
            return False
    return True


@pytest.fixture(scope="module", autouse=True, params=["arrow", "numpy"])
def parser(request):
    """Every test runs with each C parser of the fast path: pyarrow's CSV reader (when
    installed) and np.loadtxt (without pyarrow)."""
    if request.param == "arrow":
        pytest.importorskip("pyarrow")
        yield request.param
        return
    saved = csvio._arrow_columns
    csvio._arrow_columns = lambda _data, _width: None
    try:
        yield request.param
    finally:
        csvio._arrow_columns = saved


def test_fast_path_is_taken_on_a_plain_file(parser):
    text = HEADER + "\n" + ROW + "\n"
    fast = csvio._parse_simple(text, "f.csv")
    assert fast is not None
    arrays = [v for v in vars(fast).values() if isinstance(v, np.ndarray)]
    assert len(arrays) == 10 and all(v.flags.writeable for v in arrays)  # as the general reader's
    assert (csvio._arrow_columns(text.encode(), len(COLUMNS)) is not None) == (parser == "arrow")


floats = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)
cells = st.one_of(
    floats.map(repr),
    st.integers(-5, 70000).map(str),
    st.sampled_from(["nan", "inf", "-inf", "1_0", "", " 7 ", "x", "1e400", "12.5", "-0", '"3"', "0x10", "1.5e", "7\x1f", "\t8", "9\x1c"]),
)


number_like = st.text(alphabet="0123456789.+-eE \tnaif", max_size=8)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(floats.map(repr), number_like), min_size=3, max_size=3), st.integers(1, 3))
def test_arrow_reads_a_cell_as_float_does_or_refuses_it(cells, n_lines):
    """pyarrow's number parser accepts a subset of what float() accepts, with the same bits."""
    pytest.importorskip("pyarrow")
    data = ("a,b,c\n" + (",".join(cells) + "\n") * n_lines).encode()
    got = csvio._arrow_columns(data, 3)
    if got is None:
        return
    for cell, col in zip(cells, got):
        assert col.shape == (n_lines,) and col.dtype == np.float64
        want = np.float64(float(cell))  # raises if Arrow accepted what float() does not
        assert all(v.tobytes() == want.tobytes() or (v != v and want != want) for v in col)


@settings(max_examples=150, deadline=None)
@given(
    rows=st.lists(st.lists(cells, min_size=19, max_size=19), min_size=1, max_size=4),
    keep=st.booleans(),
    crlf=st.booleans(),
    blank=st.booleans(),
)
def test_same_table_or_same_error_as_the_general_reader(rows, keep, crlf, blank):
    base = ROW.split(",")
    lines = [HEADER] + [",".join(base if keep and i == 0 else r) for i, r in enumerate(rows)]
    if blank:
        lines.insert(2, "")
    text = ("\r\n" if crlf else "\n").join(lines) + "\n"
    assert same(outcome(text), general(text))


@pytest.mark.parametrize(
    "text",
    [
        HEADER + "\n" + ROW,  # no final newline
        HEADER + ",note\n" + ROW + ",5\n",  # extra column
        HEADER + "\n" + ROW + ",5\n",  # one field too many
        HEADER + "\n" + ROW[: ROW.rindex(",")] + "\n",  # one too few
        HEADER + "\n" + ROW.replace("1905", "1905.5") + "\n",  # integer column not integral
        HEADER + "\n" + ROW.replace("20.0", "2e9") + "\n",  # coordinate beyond the limit
        HEADER.replace("rx_x", "rx_x,rx_x") + "\n" + ROW + ",1\n",  # duplicate column
        HEADER + "\n" + ROW.replace("20.0", "20.0\x1f") + "\n",  # float() strips U+001F; numpy's array() does not
        HEADER + "\n" + ROW.replace("20.0", "20.0\x1f") + '\n"' + ROW.replace(",", '","') + '"\n',  # the same, general route
    ],
)
def test_edge_files(text):
    assert same(outcome(text), general(text))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(floats, floats, floats, st.integers(-1, 9_999_999), st.integers(-89, 89)), min_size=1, max_size=6))
def test_numeric_files_take_the_fast_path_and_read_the_same(values):
    lines = [HEADER]
    for t, x, y, d, delta in values:
        cells = ROW.split(",")
        cells[0], cells[3], cells[4], cells[5], cells[6] = repr(t), str(d), str(delta), repr(x), repr(y)
        lines.append(",".join(cells))
    text = "\n".join(lines) + "\n"
    assert csvio._parse_simple(text, "f.csv") is not None
    assert same(outcome(text), general(text))


#: An exported session's table: the normative columns, then the GGA quality columns.
EXPORT_HEADER = HEADER + ",fix_quality,hdop"


def test_exported_files_with_gps_quality_take_the_fast_path():
    text = EXPORT_HEADER + "\n" + ROW + ",4,0.6\n" + ROW + ",1,1.2\n"
    fast = csvio._parse_simple(text, "f.csv")
    assert fast is not None
    assert fast.fix_quality.tolist() == [4, 1] and fast.fix_quality.dtype == np.int64
    assert fast.hdop.tolist() == [0.6, 1.2]
    assert same(fast, general(text))


@settings(max_examples=150, deadline=None)
@given(
    quality=st.lists(
        st.one_of(st.integers(-2, 10).map(str), st.sampled_from(["", "1.5", "nan", "x", "4.0"])), min_size=1, max_size=4
    ),
    hdop=st.lists(st.one_of(floats.map(repr), st.sampled_from(["", "0", "-1", "inf", "nan", "0.9"])), min_size=4, max_size=4),
)
def test_gps_quality_columns_same_table_or_same_error_as_the_general_reader(quality, hdop):
    rows = [f"{ROW},{q},{h}" for q, h in zip(quality, hdop)]
    text = EXPORT_HEADER + "\n" + "\n".join(rows) + "\n"
    assert same(outcome(text), general(text))
