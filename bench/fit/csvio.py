"""Read and validate the normative CSV (BRIEF 7) for the fit.

Every problem raises :class:`FitInputError` with one line naming the file, the line and
the column, e.g. ``fit: walk.csv: line 17: column rx_x: not finite: 'nan'``. Columns may
come in any order; extra columns are ignored; blank lines are skipped. Integer columns
(seq, id, d, delta) accept integral numbers written as ``12`` or ``12.0``.
"""

from __future__ import annotations

import codecs
import csv
import io
import warnings
from pathlib import Path

import numpy as np

from emulator.files import FileRefused, open_regular
from emulator.frames.rotation import MIN_QUATERNION_NORM
from firmware_proto.sentences import MAX_ABS_DELTA, MAX_D_CM

from .table import COLUMNS, INTEGER_COLUMNS, OPTIONAL_COLUMNS, FitInputError, Table

#: Largest |coordinate| accepted (metres): beyond it differences lose all precision.
MAX_COORDINATE = 1e9
MAX_INTEGER = 2**53


def read_csv(path: str | Path, source: str | None = None) -> Table:
    """Parse and validate a normative CSV file; ``source`` names it in messages."""
    source = str(path) if source is None else source
    if Path(path).is_dir():
        raise FitInputError(f"{source}: is a directory, not a CSV file")
    try:  # a regular file only: /dev/zero or a FIFO would be read for ever
        with open_regular(path, "CSV file") as f:
            raw = f.read()
    except FileRefused as exc:
        raise FitInputError(f"{source}: {exc.reason}") from None
    except OSError as exc:
        raise FitInputError(f"{source}: cannot read: {exc.strerror or exc}") from None
    return parse_csv(raw, source)


def parse_csv(raw: bytes | str, source: str = "<csv>") -> Table:
    """Parse CSV bytes or text; see the module docstring for the rules."""
    if isinstance(raw, bytes):
        data = raw[len(codecs.BOM_UTF8) :] if raw.startswith(codecs.BOM_UTF8) else raw
        if data.isascii():  # (then it is UTF-8 text whose bytes are its characters)
            fast = _parse_simple(data, source)
            if fast is not None:
                return fast
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FitInputError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    else:
        text = raw
    if text.startswith("\ufeff"):
        text = text[1:]
    if "\x00" in text:
        raise FitInputError(f"{source}: line {text[: text.index(chr(0))].count(chr(10)) + 1}: NUL byte")
    if not isinstance(raw, bytes):
        fast = _parse_simple(text, source)
        if fast is not None:
            return fast
    lines = text.splitlines()
    try:
        records = [(i + 1, row) for i, row in enumerate(csv.reader(lines, strict=True)) if row and any(row)]
    except csv.Error as exc:
        raise FitInputError(f"{source}: line {_csv_line(exc, lines)}: malformed CSV: {exc}") from None
    if not records:
        raise FitInputError(f"{source}: empty file (no header)")
    header_line, header = records[0]
    header = [h.strip() for h in header]
    dup = sorted({h for h in header if header.count(h) > 1 and h in COLUMNS})
    if dup:
        raise FitInputError(f"{source}: line {header_line}: duplicate column {dup[0]}")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        plural = "s" if len(missing) > 1 else ""
        raise FitInputError(f"{source}: missing column{plural} {', '.join(missing)}")
    body = records[1:]
    if not body:
        raise FitInputError(f"{source}: no data rows")
    width = len(header)
    for line, row in body:
        if len(row) != width:
            raise FitInputError(f"{source}: line {line}: expected {width} fields, got {len(row)}")
    line_no = np.fromiter((line for line, _ in body), dtype=np.int64, count=len(body))
    fields = list(zip(*(row for _, row in body)))
    cols: dict[str, np.ndarray] = {}
    for name in COLUMNS:
        cells = fields[header.index(name)]
        try:
            values = np.array(cells, dtype=np.float64)
        except ValueError:  # e.g. a cell ending in U+001F, which float() strips as space
            values = None
        if values is None or any("_" in c for c in cells):
            values = _floats(source, name, cells, line_no)
        bad = ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad))
            raise FitInputError(f"{source}: line {line_no[k]}: column {name}: not finite: {cells[k].strip()!r}")
        if name in INTEGER_COLUMNS:
            bad = (values != np.round(values)) | (np.abs(values) > MAX_INTEGER)
            if bad.any():
                k = int(np.argmax(bad))
                raise FitInputError(f"{source}: line {line_no[k]}: column {name}: not an integer: {cells[k].strip()!r}")
            values = values.astype(np.int64)
        cols[name] = values
    for name in OPTIONAL_COLUMNS:
        if name in header:
            cols[name] = _optional_column(source, name, fields[header.index(name)], line_no)
    table = Table.from_mapping(source, cols, lines=line_no)
    validate(table)
    return table


#: Bytes that make an ASCII file "not simple": NUL, quoting, and line breaks other than
#: LF/CRLF that str.splitlines() would honour (the others, U+0085, U+2028 and U+2029, are
#: not ASCII: such a file never takes the fast path).
_NOT_SIMPLE = (b"\x00", b'"', b"\r", b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e")


def _parse_simple(data: bytes | str, source: str) -> Table | None:
    """One-pass parse of a plain ASCII CSV (no quotes, no blank lines, every cell a number).

    A C parser reads every cell at once, from the bytes (every check here is a bytes
    search: no decoding to str and back): pyarrow's CSV reader when it is installed
    (:func:`_arrow_columns`), else numpy's (``np.loadtxt``); both convert cells as
    ``float`` does and refuse a line with another number of columns. Returns None
    whenever the file is not that simple or any check fails, so that the general reader
    handles the file and words any error exactly as before; on success the Table is the
    same. ``data``: ASCII bytes or text, without a byte-order mark.
    """
    if isinstance(data, str):
        if not data.isascii():
            return None
        data = data.encode("ascii")
    if b"\r" in data:
        if data.endswith(b"\r\n"):
            data = data[:-2] + b"\n"
        data = data.replace(b"\r\n", b"\n")
    if any(c in data for c in _NOT_SIMPLE):
        return None
    # the body is data[start:end] (without its final newline), searched in place: no copy
    start = data.find(b"\n") + 1
    end = len(data) - 1 if data.endswith(b"\n") else len(data)
    if data.find(b"_", start) >= 0:  # float() would accept 1_000; the reader rejects it
        return None
    if start == 0 or start >= end:  # no body
        return None
    header = [h.strip() for h in data[: start - 1].decode("ascii").split(",")]
    if len(set(header)) != len(header) or any(c not in header for c in COLUMNS):
        return None
    width = len(header)
    grid = _arrow_columns(data, width)
    if grid is None:
        # a blank line anywhere after the header: np.loadtxt would skip it (with none, its
        # rows are the file's lines: a line of spaces is a line of other width). Arrow
        # refuses blank lines itself; this search costs a tenth of the read.
        if data.find(b"\n\n", start - 1) >= 0:
            return None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # e.g. numpy's "empty input" warning: not simple
                # from bytes: a StringIO of the text costs a fifth of the parse again
                grid = np.loadtxt(
                    io.BytesIO(data), dtype=np.float64, delimiter=",", comments=None, ndmin=2, encoding="latin1", skiprows=1
                )
        except (ValueError, Warning):  # a cell it cannot read, or a line with other columns
            return None
        if grid.shape[1] != width:
            return None
        grid = [np.ascontiguousarray(grid[:, j]) for j in range(width)]
    n_lines = grid[0].shape[0]
    cols: dict[str, np.ndarray] = {}
    for name in COLUMNS:
        values = grid[header.index(name)]
        if not np.isfinite(values).all():
            return None
        if name in INTEGER_COLUMNS:
            if ((values != np.round(values)) | (np.abs(values) > MAX_INTEGER)).any():
                return None
            values = values.astype(np.int64)
        cols[name] = values
    for name in OPTIONAL_COLUMNS:  # an empty HDOP cell never gets here
        if name in header:
            values = grid[header.index(name)]
            if _optional_bad(name, values, np.zeros(values.shape, bool)).any():
                return None
            cols[name] = values.astype(np.int64) if name == "fix_quality" else values
    line_no = np.arange(2, n_lines + 2, dtype=np.int64)
    table = Table.from_mapping(source, cols, lines=line_no)
    validate(table)
    return table


def _arrow_columns(data: bytes, width: int) -> list[np.ndarray] | None:
    """The body's ``width`` columns as float64 arrays by pyarrow's CSV reader (the
    ``parquet`` extra; a third of np.loadtxt's CPU time on 1e5 rows, and its own threads),
    or None: pyarrow missing, or a line or cell it refuses (np.loadtxt then decides).

    Its number parser rounds correctly, as ``float`` does: every cell it accepts reads as
    the same float (spaces and tabs around it stripped, as ``float`` does; nan/inf are
    refused by the finiteness checks after it). No null markers (an empty or "NA" cell is
    refused), no quoting (the caller has excluded quotes), every line exactly ``width``
    cells: an empty line is a row of one empty cell, refused (so its rows are the file's
    lines after the header)."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pa_csv
    except ImportError:
        return None
    names = [f"c{j}" for j in range(width)]  # header cells may repeat other names or carry spaces
    try:
        table = pa_csv.read_csv(
            io.BytesIO(data),
            read_options=pa_csv.ReadOptions(skip_rows=1, column_names=names),
            parse_options=pa_csv.ParseOptions(
                quote_char=False, double_quote=False, newlines_in_values=False, ignore_empty_lines=False
            ),
            convert_options=pa_csv.ConvertOptions(
                column_types={n: pa.float64() for n in names},
                null_values=[],
                strings_can_be_null=False,
                quoted_strings_can_be_null=False,
            ),
        )
    except pa.ArrowException:
        return None
    if table.num_columns != width or table.num_rows == 0:
        return None
    # (one chunk converts without a copy, to a read-only view of Arrow's buffer: copy it, so
    # the Table's arrays are writable, as the other routes' are)
    cols = [table.column(j).to_numpy() for j in range(width)]
    return [c if c.flags.writeable and c.flags.c_contiguous else np.array(c) for c in cols]


def _optional_column(source: str, name: str, cells, line_no) -> np.ndarray:
    """fix_quality: integers 0..8; hdop: finite numbers > 0, or an empty cell (the GGA gave
    none: NaN, the fit then takes the median HDOP); one clear error otherwise."""
    values = np.empty(len(cells))
    empty = np.zeros(len(cells), bool)
    for k, cell in enumerate(cells):
        empty[k] = not cell.strip()
        try:
            values[k] = float(cell.strip()) if "_" not in cell else float("nan")
        except ValueError:
            values[k] = float("nan")
    bad = _optional_bad(name, values, empty)
    what = "a GGA fix quality 0..8" if name == "fix_quality" else "a finite HDOP > 0"
    if bad.any():
        k = int(np.argmax(bad))
        raise FitInputError(f"{source}: line {line_no[k]}: column {name}: not {what}: {cells[k].strip()!r}")
    return values.astype(np.int64) if name == "fix_quality" else values


def _optional_bad(name: str, values: np.ndarray, empty: np.ndarray) -> np.ndarray:
    """The cells of an optional column that break its rule (``empty``: blank cells, NaN)."""
    if name == "fix_quality":
        return ~np.isfinite(values) | (values != np.round(values)) | (values < 0) | (values > 8)
    return ~(np.isfinite(values) & (values > 0)) & ~empty


def validate(table: Table) -> None:
    """Row-level checks shared by every input path (CSV, session export, emulation)."""
    n = len(table)
    if n == 0:
        raise FitInputError(f"{table.source}: no data rows")
    for name, values in (("t", table.t), ("rx", table.rx_pos), ("tx", table.tx_pos)):
        bad = ~np.isfinite(values) if values.ndim == 1 else ~np.isfinite(values).all(axis=1)
        if bad.any():
            k = int(np.argmax(bad))
            raise FitInputError(f"{table.where(k)}: {name if name == 't' else name + '_x..' + name + '_z'}: not finite")
    for prefix, pos in (("rx", table.rx_pos), ("tx", table.tx_pos)):
        big = (np.abs(pos) > MAX_COORDINATE).any(axis=1)
        if big.any():
            k = int(np.argmax(big))
            raise FitInputError(f"{table.where(k)}: {prefix}_x..{prefix}_z: coordinate beyond {MAX_COORDINATE:g} m")
    for prefix, quat in (("rx", table.rx_quat), ("tx", table.tx_quat)):
        finite = np.isfinite(quat).all(axis=1)
        if not finite.all():
            k = int(np.argmax(~finite))
            raise FitInputError(f"{table.where(k)}: {prefix}_qw..{prefix}_qz: not finite")
        scale = np.abs(quat).max(axis=1)
        norm = scale * np.sqrt(np.sum((quat / np.where(scale > 0, scale, 1.0)[:, None]) ** 2, axis=1))
        bad = ~(norm >= MIN_QUATERNION_NORM)
        if bad.any():
            k = int(np.argmax(bad))
            raise FitInputError(
                f"{table.where(k)}: {prefix}_qw..{prefix}_qz: quaternion norm {norm[k]:.3g} is below {MIN_QUATERNION_NORM:g}"
            )
    bad = table.d < -1
    if bad.any():
        k = int(np.argmax(bad))
        raise FitInputError(f"{table.where(k)}: column d: must be -1 or >= 0 cm, got {table.d[k]}")
    # The protocol's ranges (BRIEF 4): a value no receiver can send is a corrupt row.
    bad = table.d > MAX_D_CM
    if bad.any():
        k = int(np.argmax(bad))
        raise FitInputError(f"{table.where(k)}: column d: must be <= {MAX_D_CM} cm, got {table.d[k]}")
    bad = np.abs(table.delta) > MAX_ABS_DELTA
    if bad.any():
        k = int(np.argmax(bad))
        raise FitInputError(
            f"{table.where(k)}: column delta: must be within -{MAX_ABS_DELTA}..{MAX_ABS_DELTA} degrees, got {table.delta[k]}"
        )


def _floats(source: str, name: str, cells, line_no) -> np.ndarray:
    """The cells as ``float`` reads them (the fast path's np.loadtxt agrees), or one clear
    error for the first that is not a number (underscores, which float() allows, are not)."""
    values = np.empty(len(cells))
    for k, cell in enumerate(cells):
        text = cell.strip()
        try:
            if "_" in text:
                raise ValueError
            values[k] = float(text)
        except ValueError:
            shown = text if len(text) <= 40 else text[:37] + "..."
            raise FitInputError(f"{source}: line {line_no[k]}: column {name}: not a number: {shown!r}") from None
    return values


def _csv_line(exc: csv.Error, lines: list[str]) -> int:
    # csv.reader over a list counts records; the message carries no line. Find the first
    # line the strict reader rejects on its own.
    for i, line in enumerate(lines):
        try:
            list(csv.reader([line], strict=True))
        except csv.Error:
            return i + 1
    return len(lines)

