"""The stamp rule: every decoded record gets its own time, on the logger's clocks.

A read of ``n`` bytes is stamped once, when it returns: ``mono`` (s, the logging
process's ``time.monotonic()``) and ``utc`` (POSIX s, wall time). That is the arrival of
its last byte. A USB-serial adapter or a socket hands over many sentences in one read,
so the read's stamp alone would give all of them the same time. The rule:

    a record completed by the byte at offset ``k`` (0-based) of a read of ``n`` bytes is
    stamped  ``mono - (n - 1 - k) * byte_time``,  ``byte_time = 10 / baudrate`` s

(8N1 framing: 10 bits per byte at the device's configured baud rate), i.e. the time its
last byte would have arrived had the bytes come at line rate just before the read
returned; ``utc`` moves by the same amount. Stamps of one device never go backwards: a
stamp earlier than the device's previous record's is raised to it (a link faster than
its nominal baud, e.g. a socket or a pty, can deliver more bytes in a read than the
baud allows; those records then tie, which the export accepts). A record released by
``flush`` (end of input), ``stop`` (the reading stopped) or ``idle`` (a quiet link) is
stamped with that moment.

To know the byte that completed each record, a read is fed to the decoder in pieces cut
after every byte that can complete one: ``\\n`` for ``$PARVA``, ``\\r`` or ``\\n`` for NMEA
(its line splitter ends a line at either); a binary format (MAVLink) can complete a
record on any byte, so it is fed one byte at a time.

The premise: a read returns once the line goes quiet, so it never holds bytes from both
sides of a silence (the OS returns what it has; a USB adapter's latency timer flushes its
buffer after a few milliseconds without data). An adapter that packs sentences sent
with silences between them into one read compresses their spacing to line rate; the
stamps then err early by at most the silences in that read (a few ms).

Why not the sentence's own UTC (GGA, RMC and $PASHR carry one)? It is on the GPS's
clock, the receiver's epochs carry no time at all, and the export interpolates every
device on one clock, the logger's; the sentence times stay in the records (``time``)
for whoever wants them. Consequence: however the bytes of a stream are cut into reads,
a record gets the same stamp as long as each read is stamped at its last byte's arrival
and never spans a silence (tested in tests/bench/ingest/test_ingest.py with reads of 1 byte to many
sentences).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..records import RecordDecoder

_NMEA_EOL = re.compile(rb"[\r\n]")

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
        self.kinds: dict[str, int] = {}
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
        kinds = self.kinds
        if isinstance(err, dict):  # ground truth: counter increments
            for k, v in err.items():
                kinds[k] = kinds.get(k, 0) + v
        else:
            kinds[err] = kinds.get(err, 0) + 1
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
        self.pending, self.kinds, self.length = 0, {}, 0
        return rec


class StampedDecoder:
    """A device's :class:`~bench.records.RecordDecoder` with the stamp rule applied, fed
    in bounded slices, its error records sampled (:class:`ErrorSampler`)."""

    def __init__(self, decoder: RecordDecoder, baudrate: int, errors_per_second: int = ERROR_RECORDS_PER_SECOND) -> None:
        self.decoder = decoder
        self.byte_time = byte_time(baudrate)
        fmt = getattr(decoder, "format", None)  # ground truth: nmea or mavlink; receivers: none
        self.line_based = fmt != "mavlink"
        self._eol = None if fmt is None else _NMEA_EOL  # None: b"\n" only (the fast path)
        self._last = -math.inf
        self.sampler = ErrorSampler(errors_per_second)

    def stats(self) -> dict[str, int]:
        """The decoder's counters, and the error records summed instead of passed on."""
        return {**self.decoder.stats(), "error_records_suppressed": self.sampler.total}

    def _stamp(self, out: list[Stamped], records: list[dict], mono: float, utc: float) -> None:
        if records:
            if mono < self._last:
                utc += self._last - mono
                mono = self._last
            self._last = mono
            sampler = self.sampler
            if sampler.due(mono):
                out.append(Stamped(mono, utc, sampler.summary()))
            for rec in records:
                if "error" not in rec or sampler.allow(rec, mono):
                    out.append(Stamped(mono, utc, rec))

    def _release(self, out: list[Stamped], mono: float, utc: float, force: bool) -> None:
        """The pending summary, when its second is over (``force``: at the end)."""
        sampler = self.sampler
        if sampler.pending and (force or sampler.due(max(mono, self._last))):
            mono, utc = (mono, utc) if mono >= self._last else (self._last, utc + self._last - mono)
            self._last = mono
            out.append(Stamped(mono, utc, sampler.summary()))

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
        n = len(data)
        if not self.line_based:
            feed, bt = self.decoder.feed, self.byte_time
            for k in range(n):
                records = feed(data[k : k + 1])
                if records:
                    back = (n - 1 - k) * bt
                    self._stamp(out, records, mono - back, utc - back)
            return out
        start = 0
        if self._eol is not None:
            for m in self._eol.finditer(data):
                self._feed(out, data, start, m.end(), mono, utc)
                start = m.end()
        else:
            find = data.find
            while True:
                end = find(b"\n", start) + 1
                if end == 0:
                    break
                self._feed(out, data, start, end, mono, utc)
                start = end
        self._feed(out, data, start, n, mono, utc)
        return out

    def idle(self, mono: float, utc: float) -> list[Stamped]:
        """Records a quiet link releases (a receiver epoch held for a ``$PARVH``)."""
        out: list[Stamped] = []
        idle = getattr(self.decoder, "idle", None)
        if idle is not None:
            self._stamp(out, idle(), mono, utc)
        self._release(out, mono, utc, force=False)
        return out

    def stop(self, mono: float, utc: float) -> tuple[list[Stamped], int]:
        """The records pending when the reading stops, and the length of a sentence the
        stop cut (not an error: see :meth:`bench.records.RecordDecoder.stop`)."""
        records, cut = self.decoder.stop()
        out: list[Stamped] = []
        self._stamp(out, records, mono, utc)
        self._release(out, mono, utc, force=True)
        return out, cut

    def flush(self, mono: float, utc: float) -> list[Stamped]:
        """The rest at end of input."""
        out: list[Stamped] = []
        self._stamp(out, self.decoder.flush(), mono, utc)
        self._release(out, mono, utc, force=True)
        return out
