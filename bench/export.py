"""``arva-bench export``: the aligned table the fit consumes (BRIEF 7, normative columns).

One row per (epoch, slot) of every logged receiver::

    t, seq, id, d, delta, rx_x, rx_y, rx_z, rx_qw, rx_qx, rx_qy, rx_qz,
    tx_x, tx_y, tx_z, tx_qw, tx_qx, tx_qy, tx_qz, fix_quality, hdop

The first 19 are the normative columns, in that order. ``fix_quality`` (GGA fix quality,
1-8) and ``hdop`` are the receiver GPS's logged fix quality: those of the receiver fix
nearest in time to the pose lookup (of two equally near, the earlier); an empty ``hdop``
cell means the GGA carried none. ``arva-bench fit`` scales each row's GPS error by them
(docs/calibration.md, section 2); readers that know only the normative columns ignore them.

``t`` is the epoch's arrival (UTC POSIX seconds: the arrival of its last byte, by the
stamp rule of :mod:`bench.ingest.stamp`) minus ``--latency``; poses are in the session's
ENU frame (metres; quaternions ``[w, x, y, z]`` body -> ENU), interpolated at that time
from the devices' fixes (linear in position, slerp in orientation; both on the logger's
monotonic clock, so all devices share one time base). Fixes or attitudes of one device
with the same stamp (a link faster than its baud) are real data: the last of them is
used. Epochs are decoded
again from the raw bytes, so the export never depends on the derived ``.jsonl`` files.

The raw logs are streamed (:class:`bench.session.RawLog`): only epochs and fixes are kept,
however much line noise a log holds, and a read whose stamps break the session's rules
(not finite, going back, outside its span) is an error naming the file and line.

Rows are dropped, and counted, when the epoch is incomplete, when a pose cannot be
interpolated (no fix within ``--max-gap`` seconds on both sides), or when an empty slot
(d = -1) cannot be attributed to a single known transmitter.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from emulator.cli_types import origin as origin_type, output_file, positive_seconds, session_dir, signed_seconds
from emulator.frames.attitude import hpr_to_quaternion
from emulator.frames.geodesy import Origin, geodetic_to_enu
from emulator.progress import Tracker, progress
from firmware_proto.errors import InputError

from .ingest.stamp import Stamped, StampedDecoder
from .records import decoder_for, is_positioned_fix
from .session import MANIFEST, Manifest, RawLog, load_manifest, session_logs

COLUMNS = (
    "t", "seq", "id", "d", "delta",
    "rx_x", "rx_y", "rx_z", "rx_qw", "rx_qx", "rx_qy", "rx_qz",
    "tx_x", "tx_y", "tx_z", "tx_qw", "tx_qx", "tx_qy", "tx_qz",
)  # fmt: skip
#: After the normative ones: the receiver GPS fix quality (GGA, 1-8) and HDOP of each row.
GPS_QUALITY_COLUMNS = ("fix_quality", "hdop")
INT_COLUMNS = ("seq", "id", "d", "delta", "fix_quality")
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
#: Rows written between progress updates (a terminal's bar only; nothing in a pipe).
_PROGRESS_ROWS = 65536


@dataclass
class Track:
    """A device's poses over the logger's monotonic time; either part may be missing."""

    pos_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    pos: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    att_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    att: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    fixed_pos: np.ndarray | None = None
    fixed_att: np.ndarray | None = None
    fix_quality: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))  # per pos_t (GGA)
    hdop: np.ndarray = field(default_factory=lambda: np.empty(0))  # per pos_t; NaN: not given

    def gps_quality(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fix quality and HDOP of the fix nearest to each time (the earlier of two equally
        near); quality 0 and HDOP NaN where the track has no fixes (a fixed pose)."""
        if self.pos_t.size == 0:
            return np.zeros(t.size, dtype=np.int64), np.full(t.size, np.nan)
        i = np.clip(np.searchsorted(self.pos_t, t, side="left"), 1, max(self.pos_t.size - 1, 1))
        before = np.clip(i - 1, 0, self.pos_t.size - 1)
        after = np.clip(i, 0, self.pos_t.size - 1)
        k = np.where(np.abs(t - self.pos_t[before]) <= np.abs(self.pos_t[after] - t), before, after)
        return self.fix_quality[k], self.hdop[k]

    def positions(self, t: np.ndarray, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
        if self.fixed_pos is not None:
            return np.broadcast_to(self.fixed_pos, (t.size, 3)).copy(), np.ones(t.size, bool)
        ok = _bracketed(self.pos_t, t, max_gap)
        out = np.full((t.size, 3), np.nan)
        if ok.any():
            for i in range(3):
                out[ok, i] = np.interp(t[ok], self.pos_t, self.pos[:, i])
        return out, ok

    def orientations(self, t: np.ndarray, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
        if self.fixed_att is not None or (self.att_t.size == 0 and self.fixed_pos is not None):
            q = self.fixed_att if self.fixed_att is not None else IDENTITY
            return np.broadcast_to(q, (t.size, 4)).copy(), np.ones(t.size, bool)
        ok = _bracketed(self.att_t, t, max_gap)
        out = np.full((t.size, 4), np.nan)
        if ok.any():
            if self.att_t.size == 1:
                out[ok] = self.att[0]
            else:
                slerp = Slerp(self.att_t, Rotation.from_quat(self.att, scalar_first=True))
                clamped = np.clip(t[ok], self.att_t[0], self.att_t[-1])  # EDGE queries take the end
                out[ok] = slerp(clamped).as_quat(scalar_first=True)
        return out, ok


#: A query this close (s) before the first or after the last sample takes that sample:
#: two devices stamped "at the same time" arrive a few milliseconds apart.
EDGE = 0.05


def _bracketed(times: np.ndarray, t: np.ndarray, max_gap: float) -> np.ndarray:
    """True where ``t`` lies between two samples at most ``max_gap`` apart, on a sample,
    or within :data:`EDGE` of the first or last one."""
    if times.size == 0:
        return np.zeros(t.size, bool)
    i = np.searchsorted(times, t, side="right")
    inside = (i > 0) & (i < times.size)
    lo = times[np.clip(i - 1, 0, times.size - 1)]
    hi = times[np.clip(i, 0, times.size - 1)]
    ends = (np.abs(t - times[0]) <= EDGE) | (np.abs(t - times[-1]) <= EDGE)
    return ends | (inside & (hi - lo <= max_gap))


@dataclass
class ExportResult:
    columns: dict[str, np.ndarray]
    dropped: Counter
    origin: Origin
    receivers: tuple[str, ...] = ()  # the receivers (device names) whose rows the columns hold

    @property
    def rows(self) -> int:
        return int(self.columns["t"].size)


def _decode(log: RawLog, decoder, baudrate: int) -> Iterator[Stamped]:
    """Every record a device's raw reads yield, in order, stamped by the stamp rule: a
    stream (the log is read one line at a time, and only what the caller keeps stays)."""
    stamped = StampedDecoder(decoder, baudrate)
    for read in log:
        yield from stamped.feed(read.data, read.mono, read.utc)
    last = log.last
    yield from stamped.flush(last.mono if last else 0.0, last.utc if last else 0.0)


def _last_of_ties(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples sorted by time (stably), keeping the last of samples with the same time
    (records of one device may tie: see :mod:`bench.ingest.stamp`)."""
    order = np.argsort(t, kind="stable")
    t, values = t[order], values[order]
    keep = np.append(t[1:] != t[:-1], True)
    return t[keep], values[keep]


def _origin_from(manifest: Manifest, origin: list[float] | None, first_fix) -> Origin:
    if origin is not None:
        return Origin(*origin)  # LAT,LON[,ALT]
    if manifest.origin is not None:
        o = manifest.origin
        return Origin(o.lat, o.lon, o.alt)
    if first_fix is not None:
        return Origin(*first_fix)
    raise InputError("export: no origin: the session has none and no receiver GPS fix; give --origin LAT,LON,ALT")


def export_rows(directory: str | Path, origin: list[float] | None = None, latency: float = 0.0, max_gap: float = 2.0,
                receiver: str | None = None) -> ExportResult:
    """The normative table of a session as numpy columns, with the drop counts: the rows of
    every receiver one after the other, or of the device named ``receiver`` only."""
    directory = Path(directory)
    manifest = load_manifest(directory)
    devices = manifest.devices
    receivers = [name for name, dev in devices.items() if dev.kind == "arva"]
    if not receivers:
        raise InputError(f"{directory / MANIFEST}: no receiver (a device of kind arva): nothing to export")
    if receiver is not None:
        if receiver not in receivers:
            raise InputError(f"{directory}: no receiver {receiver!r} in this session (its receivers: {', '.join(receivers)})")
        devices = {name: dev for name, dev in devices.items() if dev.kind != "arva" or name == receiver}
        receivers = [receiver]
    logs = session_logs(directory, devices)  # a device that never delivered a byte has none
    if not any(name in logs for name in receivers):
        missing = ", ".join(f"{name}.raw" for name in receivers)
        raise InputError(f"{directory}: no receiver log ({missing}: missing): nothing to export")
    fixes: dict[str, list] = {}
    attitudes: dict[str, list] = {}
    epochs: dict[str, list] = {}
    for name, log in logs.items():
        dev = devices[name]
        stamped = _decode(log, decoder_for(dev.kind, dev.format), dev.baudrate)
        if dev.kind == "arva":
            epochs[name] = [(s.mono, s.utc, s.record) for s in stamped if "seq" in s.record]
            if log.bytes and not epochs[name]:
                raise InputError(f"{log.path}: {log.bytes} bytes decode to no $PARVA epoch (is {name} an ARVA receiver?)")
        else:
            for s in stamped:
                r = s.record
                if is_positioned_fix(r):
                    hdop = np.nan if r.get("hdop") is None else r["hdop"]
                    fix = (s.mono, r["lat"], r["lon"], r["alt_hae"], r.get("quality") or 0, hdop)
                    fixes.setdefault(dev.role, []).append(fix)
                elif "q" in r:
                    attitudes.setdefault(dev.role, []).append((s.mono, r["q"]))
    # The earliest receiver fix, as the logger stores it when there is no --origin.
    first_rx = min((fs[0] for role, fs in fixes.items() if role.startswith("rx") and fs), default=None)
    org = _origin_from(manifest, origin, None if first_rx is None else first_rx[1:4])
    tracks: dict[str, Track] = {}
    for role, fs in fixes.items():
        a = np.array(fs)
        e, n, u = geodetic_to_enu(a[:, 1], a[:, 2], a[:, 3], org)
        tr = tracks.setdefault(role, Track())
        tr.pos_t, kept = _last_of_ties(a[:, 0], np.c_[e, n, u, a[:, 4], a[:, 5]])
        tr.pos, tr.fix_quality, tr.hdop = kept[:, :3], kept[:, 3].astype(np.int64), kept[:, 4]
    for role, ats in attitudes.items():
        tr = tracks.setdefault(role, Track())
        tr.att_t, tr.att = _last_of_ties(np.array([m for m, _ in ats]), np.array([q for _, q in ats]))
    for tx, pose in manifest.tx_poses.items():
        tr = tracks.setdefault(f"tx{tx}", Track())
        e, n, u = geodetic_to_enu(pose.lat, pose.lon, pose.alt, org)
        tr.fixed_pos = np.array([float(e), float(n), float(u)])
        if pose.heading is not None:
            tr.fixed_att = hpr_to_quaternion(pose.heading, pose.roll, pose.pitch)
    known_tx = sorted(int(role[2:]) for role in tracks if role.startswith("tx"))

    dropped: Counter = Counter()
    parts: list[np.ndarray] = []
    for name, eps in epochs.items():
        role = devices[name].role
        rows = []
        for mono, utc, rec in eps:
            if not rec["complete"]:
                dropped["incomplete epoch"] += len(rec["slots"])
                continue
            for tx_id, d, delta in rec["slots"]:
                rows.append((mono - latency, utc - latency, rec["seq"], tx_id, d, delta))
        if not rows:
            continue
        r = np.array(rows, dtype=np.float64)
        t_query = r[:, 0]
        rx = tracks.get(role, Track())
        rx_p, ok_p = rx.positions(t_query, max_gap)
        rx_q, ok_q = rx.orientations(t_query, max_gap)
        rx_quality, rx_hdop = rx.gps_quality(t_query)
        dropped["no receiver position"] += int((~ok_p).sum())
        dropped["no receiver orientation"] += int((ok_p & ~ok_q).sum())
        keep = ok_p & ok_q
        tx_p = np.full((len(rows), 3), np.nan)
        tx_q = np.full((len(rows), 4), np.nan)
        ids = r[:, 3].astype(np.int64)
        # An empty slot carries the campaign's transmitter, if there is exactly one.
        slot_tx = np.where(ids >= 0, ids, known_tx[0] if len(known_tx) == 1 else -1)
        for tx_id in np.unique(slot_tx):
            sel = slot_tx == tx_id
            if tx_id < 0 or f"tx{tx_id}" not in tracks:
                continue
            p, okp = tracks[f"tx{tx_id}"].positions(t_query[sel], max_gap)
            q, okq = tracks[f"tx{tx_id}"].orientations(t_query[sel], max_gap)
            tx_p[sel] = np.where(okp[:, None], p, np.nan)
            tx_q[sel] = np.where((okp & okq)[:, None], q, np.nan)
        ok_tx = np.isfinite(tx_p).all(axis=1) & np.isfinite(tx_q).all(axis=1)
        dropped["no transmitter pose"] += int((keep & ~ok_tx & (slot_tx >= 0)).sum())
        unattributed = "empty slot, no transmitter known" if not known_tx else "empty slot, several transmitters"
        dropped[unattributed] += int((keep & (slot_tx < 0)).sum())
        keep &= ok_tx
        parts.append(np.column_stack([r[:, 1:], rx_p, rx_q, tx_p, tx_q, rx_quality, rx_hdop])[keep])  # COLUMNS order
    if not any(epochs.values()):
        logged = ", ".join(str(logs[name].path) for name in receivers if name in logs)
        raise InputError(f"{logged}: no complete read (empty or only a torn line): nothing to export")
    names = COLUMNS + GPS_QUALITY_COLUMNS
    table = np.concatenate(parts) if parts else np.empty((0, len(names)))
    columns = {c: table[:, i].astype(np.int64 if c in INT_COLUMNS else np.float64) for i, c in enumerate(names)}
    return ExportResult(columns, Counter({k: v for k, v in dropped.items() if v}), org, tuple(receivers))


def write_csv(columns: dict[str, np.ndarray], path: str | Path, tracker: Tracker | None = None) -> None:
    """The CSV: the normative header (then ``fix_quality, hdop`` when ``columns`` has
    them), one row per slot (µm, 1e-9 quaternion digits, HDOP to 0.01; an unknown HDOP
    is an empty cell). ``tracker`` (a progress bar) is advanced by the rows written, a
    block at a time."""
    n = columns["t"].size
    names = COLUMNS + tuple(c for c in GPS_QUALITY_COLUMNS if c in columns)
    cols = [np.asarray(columns[c]) for c in names]
    if "hdop" in columns:
        h = np.asarray(columns["hdop"], dtype=np.float64)
        cols[names.index("hdop")] = np.array(["" if v != v else f"{v:.2f}" for v in h.tolist()], dtype=object)
    with open(path, "w", newline="") as f:
        f.write(",".join(names) + "\n")
        formats = ["%d" if c in INT_COLUMNS else "%s" if c == "hdop" else "%.9f" if "_q" in c else "%.6f" for c in names]
        line = ",".join(formats) + "\n"
        for i in range(n):
            f.write(line % tuple(col[i] for col in cols))
            if tracker is not None and (i + 1) % _PROGRESS_ROWS == 0:
                tracker.advance(_PROGRESS_ROWS)


def register(sub) -> None:
    p = sub.add_parser("export", help="the aligned CSV the fit consumes", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", type=session_dir, metavar="DIR", help="session directory")
    p.add_argument("--csv", required=True, type=output_file(), metavar="FILE", help="output CSV (normative columns, then fix_quality, hdop)")
    p.add_argument("--origin", type=origin_type, metavar="LAT,LON[,ALT]", help="ENU origin (default: the session's, else the first receiver fix)")
    p.add_argument("--latency", type=signed_seconds, default=0.0, metavar="S",
                   help="the receiver's output latency: poses are taken S seconds before each epoch's arrival")
    p.add_argument("--max-gap", type=positive_seconds, default=2.0, metavar="S",
                   help="interpolate poses only between fixes at most S seconds apart (default 2)")
    p.add_argument("--receiver", metavar="NAME",
                   help="only this receiver's rows (its device name in the session; default: every receiver's, one after the other)")


def run(args: argparse.Namespace) -> int:
    with progress("export: decoding", unit="rows") as bar:
        result = export_rows(args.session, args.origin, args.latency, args.max_gap, receiver=args.receiver)
        bar.update(description="export: writing", total=result.rows, completed=0)
        try:
            write_csv(result.columns, args.csv, tracker=bar)
        except OSError as exc:
            raise InputError(f"export: {args.csv}: cannot write: {exc.strerror}") from None
    dropped = ", ".join(f"{v} {k}" for k, v in sorted(result.dropped.items()) if v) or "none"
    print(f"arva-bench: export: {result.rows} rows to {args.csv}; dropped: {dropped}", file=sys.stderr)
    return 0
