"""Decoded records of each device kind, as JSON-ready dicts, from raw bytes.

One decoder per device (:data:`RecordDecoder`): ``feed(bytes)`` returns the records those
bytes completed, ``flush()`` the rest at end of input, ``stop()`` the records still pending
when the reading stopped (not because the stream broke) and the length of an unterminated
sentence at the end, dropped without an error (its bytes are in the raw log). The logger writes them to
``<device>.jsonl``; export and replay re-derive them from the raw bytes with the same
decoders, so the raw log stays the single source of truth. Corrupt input is never
dropped silently: it becomes a record with an ``"error"`` key.

Record shapes (``mono``/``utc`` are added by the caller: the read that completed them):

* arva:      ``{"seq", "complete", "slots", ["field"], ["gap"]}`` or ``{"error", "offset", "length"}``
* gps:       ``{"sentence", "talker", "time", "lat", "lon", "alt_hae", "alt_msl", "quality",
               "sats", "hdop", "status", "mode", "speed_knots", "course", "valid"}``
* attitude:  ``{"time", "heading", "roll", "pitch", "q"}`` (+ ``"time_boot_ms"`` from MAVLink)

Ground-truth devices speak a ``format``: ``nmea`` (GGA/RMC/$PASHR, the default) or, for
attitude, ``mavlink`` (ATTITUDE_QUATERNION / ATTITUDE, the ``mavlink`` extra).
"""

from __future__ import annotations

from bench.ground_truth import Attitude, GpsFix, GroundTruthReader
from bench.ground_truth.mavlink import MavlinkAttitudeReader
from firmware_proto.decoder import Decoder
from firmware_proto.events import DecodeError, Epoch, ErrorKind

KINDS = ("arva", "gps", "attitude")
#: Wire formats a ground-truth device of each kind may speak; the first is the default.
FORMATS = {"gps": ("nmea",), "attitude": ("nmea", "mavlink")}


#: ErrorKind -> its name (a dict lookup: line noise makes one error record per byte).
_KIND_NAMES = {kind: kind.name for kind in ErrorKind}


class ArvaRecords:
    def __init__(self) -> None:
        self.decoder = Decoder()

    def feed(self, data: bytes) -> list[dict]:
        return self._records(self.decoder.feed(data))

    def idle(self) -> list[dict]:
        return self._records(self.decoder.idle())

    def flush(self) -> list[dict]:
        return self._records(self.decoder.flush())

    def stop(self) -> tuple[list[dict], int]:
        cut = self.decoder.discard_partial()
        return self._records(self.decoder.flush()), cut

    @staticmethod
    def _records(events) -> list[dict]:
        out = []
        for ev in events:
            if isinstance(ev, Epoch):
                rec = ev.to_json()
                if ev.gap:
                    rec["gap"] = ev.gap
                out.append(rec)
            elif isinstance(ev, DecodeError):
                out.append({"error": _KIND_NAMES[ev.kind], "offset": ev.offset, "length": ev.length})
        return out

    def stats(self) -> dict[str, int]:
        s = self.decoder.stats
        return {"epochs": s.epochs_complete, "incomplete": s.epochs_incomplete, "errors": sum(s.errors.values()),
                "seq_gaps": s.seq_gaps}


def _iso(dt) -> str | None:
    return None if dt is None else dt.isoformat().replace("+00:00", "Z")


#: GpsFix fields a gps record holds as they are, in the record's order (after sentence,
#: talker and time; then valid).
GPS_FIELDS = ("lat", "lon", "alt_hae", "alt_msl", "quality", "sats", "hdop", "status", "mode", "speed_knots", "course")
#: Reader counters that mean rejected input (``junk_bytes`` counts bytes, not lines).
GT_ERROR_KEYS = ("bad_checksum", "no_checksum", "non_ascii", "malformed", "overlong", "fragments", "junk_bytes")


def is_positioned_fix(record: dict) -> bool:
    """A valid GGA record with an ellipsoid height: a position the export and the origin use."""
    return record.get("sentence") == "GGA" and bool(record.get("valid")) and record.get("alt_hae") is not None


class GroundTruthRecords:
    """GPS fixes and/or $PASHR attitudes: one reader handles both on one stream.

    Input the reader rejects is flagged with an ``{"error": {counter: increment}}``
    record for the read that carried it (the bytes themselves are in the raw log).
    """

    def __init__(self, fmt: str = "nmea") -> None:
        if fmt not in ("nmea", "mavlink"):
            raise ValueError(f"ground-truth format must be nmea or mavlink, got {fmt!r}")
        self.format = fmt
        # MavlinkAttitudeReader imports pymavlink (the mavlink extra) when it is made.
        self.reader = MavlinkAttitudeReader() if fmt == "mavlink" else GroundTruthReader()
        self.records = 0
        self.errors = 0

    def feed(self, data: bytes) -> list[dict]:
        return self._flagged(lambda: self.reader.feed(data))

    def flush(self) -> list[dict]:
        return self._flagged(self.reader.flush)

    def stop(self) -> tuple[list[dict], int]:
        return [], self.reader.pending  # records complete with their line: none is pending

    def _flagged(self, step) -> list[dict]:
        stats = self.reader.stats
        before = [stats[k] for k in GT_ERROR_KEYS]
        out = self._records(step())
        delta = {k: stats[k] - b for k, b in zip(GT_ERROR_KEYS, before) if stats[k] != b}
        if delta:
            self.errors += sum(v for k, v in delta.items() if k != "junk_bytes") or 1
            out.append({"error": delta})
        return out

    def _records(self, items) -> list[dict]:
        out = []
        for r in items:
            time = _iso(r.utc) or (None if r.time_of_day is None else r.time_of_day.isoformat())
            if isinstance(r, GpsFix):
                fields = {k: getattr(r, k) for k in GPS_FIELDS}
                out.append({"sentence": r.sentence, "talker": r.talker, "time": time, **fields, "valid": r.valid})
            elif isinstance(r, Attitude):
                rec = {"time": time, "heading": r.heading, "roll": r.roll, "pitch": r.pitch, "q": list(r.quaternion)}
                if r.time_boot_ms is not None:
                    rec["time_boot_ms"] = r.time_boot_ms
                out.append(rec)
        self.records += len(out)
        return out

    def stats(self) -> dict[str, int]:
        return {"records": self.records, "errors": self.errors, "ignored": self.reader.stats["ignored"]}


RecordDecoder = ArvaRecords | GroundTruthRecords


def decoder_for(kind: str, fmt: str | None = None) -> RecordDecoder:
    """The decoder of a device ``kind`` speaking ``fmt`` (None: the kind's default)."""
    if kind == "arva":
        return ArvaRecords()
    if kind in FORMATS:
        fmt = FORMATS[kind][0] if fmt is None else fmt
        if fmt not in FORMATS[kind]:
            raise ValueError(f"a {kind} device cannot speak {fmt!r} (one of: {', '.join(FORMATS[kind])})")
        return GroundTruthRecords(fmt)
    raise ValueError(f"unknown device kind {kind!r}")
