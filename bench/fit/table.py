"""The normative fit table (BRIEF 7): one row per (epoch, slot), poses in ENU.

Columns ``t, seq, id, d, delta, rx_x, rx_y, rx_z, rx_qw, rx_qx, rx_qy, rx_qz, tx_x, tx_y,
tx_z, tx_qw, tx_qx, tx_qy, tx_qz``; rows with d = -1 carry the pose of the campaign's
transmitter. :class:`Table` holds them as numpy arrays; ``lines`` maps each row to the
line of the file it came from, so later checks can still name it.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import InputError

COLUMNS: tuple[str, ...] = (
    "t", "seq", "id", "d", "delta",
    "rx_x", "rx_y", "rx_z", "rx_qw", "rx_qx", "rx_qy", "rx_qz",
    "tx_x", "tx_y", "tx_z", "tx_qw", "tx_qx", "tx_qy", "tx_qz",
)  # fmt: skip
INTEGER_COLUMNS = frozenset({"seq", "id", "d", "delta"})
#: Optional columns after the normative ones: the receiver GPS fix's GGA quality (0-8)
#: and HDOP, which set each row's share of the GPS error (:func:`gps_scale`).
OPTIONAL_COLUMNS: tuple[str, ...] = ("fix_quality", "hdop")
#: Typical horizontal 1-sigma (m) per unit HDOP for each GGA fix quality: 1 GPS, 2 DGPS/SBAS,
#: 4 RTK fixed, 5 RTK float, 6 dead reckoning; others count as plain GPS.
QUALITY_SIGMA = {1: 1.5, 2: 0.5, 3: 1.5, 4: 0.02, 5: 0.3, 6: 3.0}


class FitInputError(InputError):
    """Input the fit cannot use; ``str()`` is one line starting with ``fit: ``."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(f"fit: {reason}")


@dataclass
class Table:
    source: str
    t: NDArray[np.float64]
    seq: NDArray[np.int64]
    id: NDArray[np.int64]
    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    rx_pos: NDArray[np.float64]  # (N, 3)
    rx_quat: NDArray[np.float64]  # (N, 4) [w, x, y, z]
    tx_pos: NDArray[np.float64]
    tx_quat: NDArray[np.float64]
    lines: NDArray[np.int64] | None = None  # file line of each row (1 = header)
    fix_quality: NDArray[np.int64] | None = None  # optional: GGA fix quality of the receiver pose
    hdop: NDArray[np.float64] | None = None  # optional: its HDOP

    def __len__(self) -> int:
        return int(self.d.shape[0])

    @classmethod
    def from_columns(cls, source: str, t, seq, id, d, delta, rx_pos, rx_quat, tx_pos, tx_quat, lines=None) -> "Table":
        f = lambda a, shape: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(shape))  # noqa: E731
        i = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.int64).reshape(-1))  # noqa: E731
        n = np.asarray(d).reshape(-1).shape[0]
        return cls(
            source, f(t, (n,)), i(seq), i(id), i(d), i(delta),
            f(rx_pos, (n, 3)), f(rx_quat, (n, 4)), f(tx_pos, (n, 3)), f(tx_quat, (n, 4)),
            None if lines is None else i(lines),
        )  # fmt: skip

    @classmethod
    def from_mapping(cls, source: str, cols: dict[str, ArrayLike], lines=None) -> "Table":
        """From a dict of the normative columns (extra keys ignored)."""
        missing = [c for c in COLUMNS if c not in cols]
        if missing:
            raise FitInputError(f"{source}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
        g = lambda *names: np.stack([np.asarray(cols[c], dtype=np.float64) for c in names], axis=-1)  # noqa: E731
        table = cls.from_columns(
            source,
            cols["t"], cols["seq"], cols["id"], cols["d"], cols["delta"],
            g("rx_x", "rx_y", "rx_z"), g("rx_qw", "rx_qx", "rx_qy", "rx_qz"),
            g("tx_x", "tx_y", "tx_z"), g("tx_qw", "tx_qx", "tx_qy", "tx_qz"),
            lines,
        )  # fmt: skip
        if "fix_quality" in cols:
            table.fix_quality = np.asarray(cols["fix_quality"], dtype=np.int64).reshape(-1)
        if "hdop" in cols:
            table.hdop = np.asarray(cols["hdop"], dtype=np.float64).reshape(-1)
        return table

    def columns(self) -> dict[str, NDArray]:
        out: dict[str, NDArray] = {"t": self.t, "seq": self.seq, "id": self.id, "d": self.d, "delta": self.delta}
        for prefix, pos, quat in (("rx", self.rx_pos, self.rx_quat), ("tx", self.tx_pos, self.tx_quat)):
            for k, c in enumerate("xyz"):
                out[f"{prefix}_{c}"] = pos[:, k]
            for k, c in enumerate(("qw", "qx", "qy", "qz")):
                out[f"{prefix}_{c}"] = quat[:, k]
        return out

    def subset(self, mask: NDArray[np.bool_]) -> "Table":
        return Table(
            self.source, self.t[mask], self.seq[mask], self.id[mask], self.d[mask], self.delta[mask],
            self.rx_pos[mask], self.rx_quat[mask], self.tx_pos[mask], self.tx_quat[mask],
            None if self.lines is None else self.lines[mask],
            None if self.fix_quality is None else self.fix_quality[mask],
            None if self.hdop is None else self.hdop[mask],
        )  # fmt: skip

    def where(self, row: int) -> str:
        """``FILE: line N`` (or ``row N`` without line numbers) for error messages."""
        if self.lines is not None:
            return f"{self.source}: line {int(self.lines[row])}"
        return f"{self.source}: row {row}"

    def write_csv(self, path: str | Path | io.TextIOBase) -> None:
        """Write the normative CSV (header + one line per row); floats read back exactly."""
        cols = self.columns()
        parts = []
        for name in COLUMNS:
            a = cols[name]
            parts.append(a.astype(str))  # shortest text that reads back to the same float
        body = "\n".join(",".join(row) for row in zip(*parts))
        text = ",".join(COLUMNS) + "\n" + (body + "\n" if len(self) else "")
        if isinstance(path, (str, Path)):
            Path(path).write_text(text)
        else:
            path.write(text)


#: An interval between consecutive time stamps longer than this many times their median
#: counts as a gap (:class:`TimeStamps`).
GAP_FACTOR = 3.0
#: Largest |t| the fit accepts (s; 30,000 years): no clock stamps beyond it, and the
#: float64 differences of the time-block sums stay exact to 1e-4 s.
MAX_TIME = 1e12


@dataclass(frozen=True)
class TimeStamps:
    """What the time column of a table holds beyond one stamp per epoch (counted, never a
    reason to refuse: :func:`check_times`).

    An epoch is a run of consecutive rows with the same ``(t, seq)``: its slots, one row
    each (several transmitters, or empty slots with id -1, legitimately share t).
    ``duplicated``: epochs stamped with the same t as the epoch before them (another seq):
    a clock that stuttered or a coarse stamp. ``repeated``: rows whose (t, seq, id), id >=
    0, already occurred in their epoch (one slot logged twice). Both are kept as readings.
    ``gaps``: intervals between consecutive distinct stamps longer than
    :data:`GAP_FACTOR` times their median; ``largest_gap``: the longest interval (s)."""

    epochs: int
    duplicated: int
    repeated: int
    gaps: int
    largest_gap: float

    def summary(self) -> str | None:
        """One note for the fit's summary, or None when there is nothing to say."""
        parts = []
        if self.duplicated:
            parts.append(f"{self.duplicated} epoch{'s' if self.duplicated > 1 else ''} shared the stamp of the one before")
        if self.repeated:
            parts.append(f"{self.repeated} row{'s' if self.repeated > 1 else ''} repeated a slot (t, seq, id) of their epoch")
        if self.gaps:
            parts.append(f"{self.gaps} gap{'s' if self.gaps > 1 else ''} in the time stamps (the largest {self.largest_gap:.6g} s)")
        if not parts:
            return None
        kept = " (kept as readings; rows sharing a stamp share one pose in the time-offset track)" if self.duplicated or self.repeated else ""
        return "time stamps: " + "; ".join(parts) + kept

    def to_json(self) -> dict:
        return {
            "epochs": self.epochs, "duplicated": self.duplicated, "repeated": self.repeated,
            "gaps": self.gaps, "largest_gap_seconds": self.largest_gap,
        }  # fmt: skip


def check_times(table: Table) -> TimeStamps:
    """The time column's order (a stamp before the one above it: :class:`FitInputError`
    naming the line) and what it holds beyond one stamp per epoch (:class:`TimeStamps`)."""
    t = table.t
    n = t.shape[0]
    if n == 0:
        return TimeStamps(0, 0, 0, 0, 0.0)
    big = np.abs(t) > MAX_TIME
    if big.any():
        k = int(np.argmax(big))
        raise FitInputError(f"{table.where(k)}: t = {float(t[k])!r} is beyond {MAX_TIME:g} s")
    back = np.flatnonzero(t[1:] < t[:-1])
    if back.size:
        k = int(back[0]) + 1
        raise FitInputError(f"{table.where(k)}: t goes backwards ({float(t[k])!r} after {float(t[k - 1])!r})")
    new_epoch = np.ones(n, bool)
    new_epoch[1:] = (t[1:] != t[:-1]) | (table.seq[1:] != table.seq[:-1])
    starts = np.flatnonzero(new_epoch)
    duplicated = int(np.sum(t[starts[1:]] == t[starts[:-1]]))
    epoch = np.cumsum(new_epoch) - 1
    slots = table.id >= 0
    keys = np.stack([epoch[slots], table.id[slots]], axis=1)
    repeated = int(keys.shape[0] - np.unique(keys, axis=0).shape[0]) if keys.size else 0
    stamps = np.unique(t)
    dt = np.diff(stamps)
    if dt.size == 0:
        return TimeStamps(int(starts.size), duplicated, repeated, 0, 0.0)
    gaps = int(np.sum(dt > GAP_FACTOR * float(np.median(dt))))
    return TimeStamps(int(starts.size), duplicated, repeated, gaps, float(dt.max()))


def gps_scale(table: Table) -> NDArray[np.float64] | None:
    """Each row's GPS error relative to the table's median row: QUALITY_SIGMA[quality] x
    HDOP (either may be missing), divided by its median; None without both columns.
    The fitted gps_sigma is then the error of a median row. Quality 0 (no fix) rows get
    a factor 1e3: the fit leaves them out (their pose says nothing). A row without an
    HDOP (NaN: the GGA gave none) takes the median of the others (1 if none has one).
    None too when no row has a fix (quality 0 everywhere: a fixed receiver pose)."""
    if table.fix_quality is None and table.hdop is None:
        return None
    if table.fix_quality is not None and not np.any(table.fix_quality > 0):
        # no row has a GPS fix (a fixed, surveyed receiver pose exports quality 0): the
        # columns say nothing about the rows' relative GPS error, so they scale nothing
        return None
    n = len(table)
    q = np.ones(n, dtype=np.int64) if table.fix_quality is None else table.fix_quality
    sig = _quality_sigma(q)
    if table.hdop is not None:
        known = np.isfinite(table.hdop)
        fill = float(np.median(table.hdop[known])) if known.any() else 1.0
        sig = sig * np.where(known, table.hdop, fill)
    valid = q > 0
    med = float(np.median(sig[valid])) if valid.any() else 1.0
    out = sig / (med if med > 0 else 1.0)
    return np.where(valid, out, 1e3)


def _quality_sigma(q: NDArray[np.int64]) -> NDArray[np.float64]:
    lut = np.full(10, 1.5)
    for k, v in QUALITY_SIGMA.items():
        lut[k] = v
    return lut[np.clip(q, 0, 9)]
