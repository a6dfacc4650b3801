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
and never spans a silence (tested in tests/test_ingest.py with reads of 1 byte to many
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


class StampedDecoder:
    """A device's :class:`~bench.records.RecordDecoder` with the stamp rule applied."""

    def __init__(self, decoder: RecordDecoder, baudrate: int) -> None:
        self.decoder = decoder
        self.byte_time = byte_time(baudrate)
        fmt = getattr(decoder, "format", None)  # ground truth: nmea or mavlink; receivers: none
        self.line_based = fmt != "mavlink"
        self._eol = None if fmt is None else _NMEA_EOL  # None: b"\n" only (the fast path)
        self._last = -math.inf

    def _stamp(self, out: list[Stamped], records: list[dict], mono: float, utc: float) -> None:
        if records:
            if mono < self._last:
                utc += self._last - mono
                mono = self._last
            self._last = mono
            for rec in records:
                out.append(Stamped(mono, utc, rec))

    def feed(self, data: bytes, mono: float, utc: float) -> list[Stamped]:
        """Records completed by one read of ``data`` stamped ``mono``/``utc`` (its end)."""
        out: list[Stamped] = []
        n = len(data)
        feed, bt = self.decoder.feed, self.byte_time
        if not self.line_based:
            for k in range(n):
                records = feed(data[k : k + 1])
                if records:
                    back = (n - 1 - k) * bt
                    self._stamp(out, records, mono - back, utc - back)
            return out
        if self._eol is not None:
            start = 0
            for m in self._eol.finditer(data):
                end = m.end()
                records = feed(data[start:end])
                if records:
                    back = (n - end) * bt
                    self._stamp(out, records, mono - back, utc - back)
                start = end
            if start < n:
                self._stamp(out, feed(data[start:]), mono, utc)
            return out
        start = 0
        find = data.find
        while True:
            end = find(b"\n", start) + 1
            if end == 0 or end == n:
                records = feed(data[start:] if start else data)
                self._stamp(out, records, mono, utc)
                return out
            records = feed(data[start:end])
            if records:
                back = (n - end) * bt
                self._stamp(out, records, mono - back, utc - back)
            start = end

    def idle(self, mono: float, utc: float) -> list[Stamped]:
        """Records a quiet link releases (a receiver epoch held for a ``$PARVH``)."""
        out: list[Stamped] = []
        idle = getattr(self.decoder, "idle", None)
        if idle is not None:
            self._stamp(out, idle(), mono, utc)
        return out

    def stop(self, mono: float, utc: float) -> tuple[list[Stamped], int]:
        """The records pending when the reading stops, and the length of a sentence the
        stop cut (not an error: see :meth:`bench.records.RecordDecoder.stop`)."""
        records, cut = self.decoder.stop()
        out: list[Stamped] = []
        self._stamp(out, records, mono, utc)
        return out, cut

    def flush(self, mono: float, utc: float) -> list[Stamped]:
        """The rest at end of input."""
        out: list[Stamped] = []
        self._stamp(out, self.decoder.flush(), mono, utc)
        return out
