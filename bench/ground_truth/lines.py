"""Bytes from a device -> complete ``$...`` lines, in bounded memory, never stalling.

NMEA 0183 sentences start with ``$`` and end with CR LF. Real ports also carry binary
protocols (UBX, SiRF, Ashtech), log comments, line noise and sentences cut off by a
reconnect. The splitter:

* starts a line at ``$`` and ends it at the first CR or LF (either alone is accepted);
* restarts at the *last* ``$`` of a line if one occurs inside it (the text before it was a
  truncated sentence: counted in ``fragments``), so a good sentence right after junk or a
  torn sentence is never lost;
* drops a line longer than ``max_line`` bytes, including ``$`` and excluding CR LF
  (``overlong``) -- whether or not its end has arrived yet -- and looks for the next
  ``$``: memory stays below ``max_line`` bytes plus one chunk whatever is fed;
* counts bytes outside any line, except CR and LF, as ``junk_bytes``.

NMEA's own limit is 82 characters with CR LF; high-precision receivers (u-blox HPNMEA,
SkyTraq PSTI) send longer ones, so the default limit is 256.
"""

from __future__ import annotations

import re
from collections import Counter

from pynmeagps import NMEAMessage

from .nmea import FieldError, parse_checked
from .utc import DayTracker

DEFAULT_MAX_LINE = 256

_EOL = re.compile(rb"[\r\n]")


class LineSplitter:
    """Incremental splitter; ``feed(bytes) -> list[bytes]`` lines without CR/LF.

    ``stats`` (a Counter, shareable with the parsers) gains ``bytes``, ``lines``,
    ``junk_bytes``, ``fragments`` and ``overlong``.
    """

    def __init__(self, max_line: int = DEFAULT_MAX_LINE, stats: Counter[str] | None = None) -> None:
        if max_line < 8:
            raise ValueError("max_line must be at least 8 bytes")
        self.max_line = max_line
        self.stats: Counter[str] = Counter() if stats is None else stats
        self._buf = bytearray()

    def _junk(self, start: int, end: int) -> None:
        if end > start:
            buf = self._buf
            junk = end - start - buf.count(b"\r", start, end) - buf.count(b"\n", start, end)
            if junk:
                self.stats["junk_bytes"] += junk

    def feed(self, data: bytes) -> list[bytes]:
        """Append ``data``; return the lines it completed, oldest first."""
        st = self.stats
        st["bytes"] += len(data)
        buf = self._buf
        buf += data
        n = len(buf)
        lines: list[bytes] = []
        pos = 0
        max_line = self.max_line
        while pos < n:
            start = buf.find(b"$", pos)
            if start < 0:
                self._junk(pos, n)
                pos = n
                break
            self._junk(pos, start)
            m = _EOL.search(buf, start)
            if m is None:
                if n - start <= max_line:
                    pos = start  # an incomplete line: wait for more bytes
                    break
                # Too long already; resume at the next '$', if any, inside it.
                st["overlong"] += 1
                nxt = buf.find(b"$", start + 1)
                pos = nxt if nxt >= 0 else n
                continue
            end = m.start()
            last = buf.rfind(b"$", start + 1, end)
            if last >= 0:
                st["fragments"] += 1
                self._junk(start, last)
                start = last
            if end - start > max_line:
                st["overlong"] += 1
            else:
                lines.append(bytes(buf[start:end]))
            pos = end + 1
        del buf[:pos]
        st["lines"] += len(lines)
        return lines

    def flush(self) -> list[bytes]:
        """At end of input: the pending unterminated line, if any, as a last line."""
        if not self._buf:
            return []
        lines = self.feed(b"\n")
        self.stats["bytes"] -= 1  # the terminator was ours, not the device's
        return lines

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the end of a line (always <= ``max_line``)."""
        return len(self._buf)


class SentenceReader:
    """Base of the streaming readers: bytes -> lines (:class:`LineSplitter`) -> records.

    Subclasses implement :meth:`handle_line` (one complete line -> a record or None,
    counting what it rejects in ``stats``). ``stats`` and the date ``tracker`` may be
    shared between readers of one stream.
    """

    def __init__(self, *, tracker=None, max_line: int = DEFAULT_MAX_LINE, stats: Counter[str] | None = None) -> None:
        self.stats: Counter[str] = Counter() if stats is None else stats
        self.tracker = DayTracker() if tracker is None else tracker
        self._lines = LineSplitter(max_line, self.stats)

    def feed(self, data: bytes) -> list:
        """Records completed by ``data``, in stream order."""
        return self._handle(self._lines.feed(data))

    def flush(self) -> list:
        """At end of input: parse a last line that lacked its CR LF."""
        return self._handle(self._lines.flush())

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the end of a line (at most ``max_line``)."""
        return self._lines.pending

    def _handle(self, lines: list[bytes]) -> list:
        return [rec for rec in map(self.handle_line, lines) if rec is not None]

    def handle_line(self, line: bytes):
        """One complete line (``$`` ... ``*hh``, no CR LF) -> a record, or None (counted):
        ``ignored`` if :meth:`accepts` refuses it, the reason of :func:`.nmea.parse_checked`,
        ``malformed`` if :meth:`decode` refuses a field (a record it counts itself)."""
        if not self.accepts(line):
            self.stats["ignored"] += 1
            return None
        msg = parse_checked(line, self.stats)
        if msg is None:
            return None
        try:
            return self.decode(msg, line)
        except (FieldError, ValueError, TypeError):
            self.stats["malformed"] += 1
            return None

    def accepts(self, line: bytes) -> bool:
        """Whether this reader reads ``line`` (a sentence it knows)."""
        raise NotImplementedError

    def decode(self, msg: NMEAMessage, line: bytes):
        """The record of a checked sentence, counted in ``stats``, or None (a sentence that
        only updates state); :class:`.nmea.FieldError` (or ValueError, TypeError) for a
        field it refuses, before anything is counted."""
        raise NotImplementedError
