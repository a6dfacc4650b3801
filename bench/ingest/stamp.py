"""The stamp rule: every decoded record gets its own time, on the logger's clocks.

A read of ``n`` bytes is stamped once, when it returns: ``mono`` (s, the logging
process's ``time.monotonic()``) and ``utc`` (POSIX s, wall time). A record completed by
the byte at offset ``k`` (0-based) of that read is stamped ``mono - (n - 1 - k) *
byte_time``, ``byte_time = 10 / baudrate`` s (8N1), and ``utc`` moves by the same
amount. One device's stamps never go backwards: an earlier stamp is raised to the
previous record's (the records tie, which the export accepts). A record released by
``flush`` (end of input), ``stop`` (the reading stopped) or ``idle`` (a quiet link) is
stamped with that moment. The rule, its premise (a read never spans a silence) and why
the sentences' own UTC is not used: docs/bench.md, section 4.

To know the byte that completed each record, a read is fed to the decoder in pieces cut
after every byte that can complete one: ``\\n`` for ``$PARVA``, ``\\r`` or ``\\n`` for
NMEA; a binary format (MAVLink) one byte at a time. However the bytes of a stream are cut
into reads, a record gets the same stamp (tests/bench/ingest/test_ingest.py).
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass

from ..records import RecordDecoder

#: Bytes after which a record may be complete, by the decoder's format (None: a receiver).
_RECORD_END = {
    None: re.compile(rb"\n"),  # $PARVA
    "nmea": re.compile(rb"[\r\n]"),  # the line splitter ends a line at either
    "mavlink": re.compile(rb".", re.DOTALL),  # binary: any byte
}

#: Bits on the wire per byte (start, 8 data, stop).
BITS_PER_BYTE = 10
#: Most bytes fed to a decoder at once: bounds the events of line noise held in memory.
FEED_SLICE = 4096
#: Error records passed on per device and second of its stamps; the rest are summed.
ERROR_RECORDS_PER_SECOND = 10


def byte_time(baudrate: int) -> float:
    """Seconds one byte takes on a link at ``baudrate`` bit/s (8N1)."""
    return BITS_PER_BYTE / baudrate


@dataclass(frozen=True, slots=True)
class Stamped:
    """One decoded record with its own stamp: ``mono`` (s, logger's monotonic clock) and
    ``utc`` (POSIX s)."""

    mono: float
    utc: float
    record: dict

    def as_json(self) -> dict:
        """The record as the session's ``<device>.jsonl`` stores it (µs stamps)."""
        return {"mono": round(self.mono, 6), "utc": round(self.utc, 6), **self.record}


class ErrorSampler:
    """Which error records of one device are passed on: the first ``per_second`` of each
    second of stamps (windows start at the first error stamped after the previous window
    ended); the others are summed into a pending ``suppressed`` record."""

    def __init__(self, per_second: int = ERROR_RECORDS_PER_SECOND) -> None:
        self.per_second = per_second
        self.window_end = -math.inf
        self.passed = 0  # in the current window
        self.pending = 0  # suppressed, not reported yet
        self.kinds: Counter[str] = Counter()
        self.length = 0
        self.total = 0  # suppressed since the start

    def allow(self, record: dict, mono: float) -> bool:
        """True: pass ``record`` on; False: it is counted in the pending summary."""
        if mono >= self.window_end:
            self.window_end = mono + 1.0
            self.passed = 0
        if self.passed < self.per_second:
            self.passed += 1
            return True
        self.pending += 1
        self.total += 1
        err = record["error"]
        if isinstance(err, dict):  # ground truth: counter increments
            self.kinds.update(err)
        else:
            self.kinds[err] += 1
            self.length += record.get("length", 0)
        return False

    def due(self, mono: float) -> bool:
        """A summary is pending and its second is over."""
        return self.pending > 0 and mono >= self.window_end

    def summary(self) -> dict:
        """The pending summary record (and a fresh count)."""
        rec: dict = {"suppressed": self.pending, "kinds": self.kinds}
        if self.length:
            rec["length"] = self.length
        self.pending, self.kinds, self.length = 0, Counter(), 0
        return rec


class StampedDecoder:
    """A device's :data:`~bench.records.RecordDecoder` with the stamp rule applied, fed in
    bounded slices, its error records sampled (:class:`ErrorSampler`)."""

    def __init__(self, decoder: RecordDecoder, baudrate: int, errors_per_second: int = ERROR_RECORDS_PER_SECOND) -> None:
        self.decoder = decoder
        self.byte_time = byte_time(baudrate)
        self._record_end = _RECORD_END[getattr(decoder, "format", None)]  # receivers have no format
        self._last = -math.inf
        self.sampler = ErrorSampler(errors_per_second)

    def stats(self) -> dict[str, int]:
        """The decoder's counters, and the error records summed instead of passed on."""
        return {**self.decoder.stats(), "error_records_suppressed": self.sampler.total}

    def _monotone(self, mono: float, utc: float) -> tuple[float, float]:
        """The stamp raised to the previous record's when earlier; it becomes the previous."""
        if mono < self._last:
            mono, utc = self._last, utc + (self._last - mono)
        self._last = mono
        return mono, utc

    def _stamp(self, out: list[Stamped], records: list[dict], mono: float, utc: float) -> None:
        if records:
            mono, utc = self._monotone(mono, utc)
            sampler = self.sampler
            if sampler.due(mono):
                out.append(Stamped(mono, utc, sampler.summary()))
            for rec in records:
                if "error" not in rec or sampler.allow(rec, mono):
                    out.append(Stamped(mono, utc, rec))

    def _feed(self, out: list[Stamped], data: bytes, start: int, end: int, mono: float, utc: float) -> None:
        """Feed ``data[start:end]`` in slices of at most FEED_SLICE bytes; the records of
        a slice are stamped at its last byte (``data`` is the whole read, ending at ``mono``)."""
        feed, bt, n = self.decoder.feed, self.byte_time, len(data)
        while start < end:
            stop = min(end, start + FEED_SLICE)
            records = feed(data[start:stop] if start or stop < n else data)
            if records:
                back = (n - stop) * bt
                self._stamp(out, records, mono - back, utc - back)
            start = stop

    def feed(self, data: bytes, mono: float, utc: float) -> list[Stamped]:
        """Records completed by one read of ``data`` stamped ``mono``/``utc`` (its end)."""
        out: list[Stamped] = []
        start = 0
        for m in self._record_end.finditer(data):
            self._feed(out, data, start, m.end(), mono, utc)
            start = m.end()
        self._feed(out, data, start, len(data), mono, utc)
        return out

    def _released(self, records: list[dict], mono: float, utc: float, force: bool) -> list[Stamped]:
        """``records`` released at ``mono``/``utc``, then the pending error summary when
        its second is over (``force``: at the end, always)."""
        out: list[Stamped] = []
        self._stamp(out, records, mono, utc)
        sampler = self.sampler
        if sampler.pending and (force or sampler.due(max(mono, self._last))):
            out.append(Stamped(*self._monotone(mono, utc), sampler.summary()))
        return out

    def idle(self, mono: float, utc: float) -> list[Stamped]:
        """Records a quiet link releases (a receiver epoch held for a ``$PARVH``)."""
        idle = getattr(self.decoder, "idle", None)
        return self._released([] if idle is None else idle(), mono, utc, force=False)

    def stop(self, mono: float, utc: float) -> tuple[list[Stamped], int]:
        """The records pending when the reading stops, and the length of a sentence the
        stop cut (not an error: see :mod:`bench.records`)."""
        records, cut = self.decoder.stop()
        return self._released(records, mono, utc, force=True), cut

    def flush(self, mono: float, utc: float) -> list[Stamped]:
        """The rest at end of input."""
        return self._released(self.decoder.flush(), mono, utc, force=True)
