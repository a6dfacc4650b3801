"""One stream carrying both GPS and attitude (an INS such as the OxTS in gpsd's rst39.log).

:class:`GroundTruthReader` splits the bytes once and hands GGA/RMC to a
:class:`~bench.ground_truth.gps.GpsReader` and ``$PASHR`` to an
:class:`~bench.ground_truth.attitude.AttitudeReader` that share one
:class:`~bench.ground_truth.utc.DayTracker` (so attitudes get the RMC date) and one
``stats`` Counter. Other sentences are counted as ``ignored``.
"""

from __future__ import annotations

from collections import Counter
from datetime import datetime

from .attitude import Attitude, AttitudeReader
from .gps import GpsFix, GpsReader
from .lines import DEFAULT_MAX_LINE, LineSplitter
from .nmea import sentence_type
from .utc import DayTracker

Record = GpsFix | Attitude


class GroundTruthReader:
    """``feed(bytes) -> list[GpsFix | Attitude]`` in stream order; never raises on data."""

    def __init__(self, *, start: datetime | None = None, max_line: int = DEFAULT_MAX_LINE) -> None:
        self.stats: Counter[str] = Counter()
        self.tracker = DayTracker(start)
        self.gps = GpsReader(tracker=self.tracker, stats=self.stats)
        self.attitude = AttitudeReader(tracker=self.tracker, stats=self.stats)
        self._lines = LineSplitter(max_line, self.stats)

    def feed(self, data: bytes) -> list[Record]:
        """Records completed by ``data``."""
        return self._handle(self._lines.feed(data))

    def flush(self) -> list[Record]:
        """At end of input: parse a last line that lacked its CR LF."""
        return self._handle(self._lines.flush())

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the end of a line (at most ``max_line``)."""
        return self._lines.pending

    def _handle(self, lines: list[bytes]) -> list[Record]:
        out: list[Record] = []
        for line in lines:
            rec = self.attitude.handle_line(line) if sentence_type(line) == b"PASHR" else self.gps.handle_line(line)
            if rec is not None:
                out.append(rec)
        return out
