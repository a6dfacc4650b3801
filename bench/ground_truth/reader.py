"""One stream carrying both GPS and attitude (an INS such as the OxTS in gpsd's rst39.log).

:class:`GroundTruthReader` splits the bytes once and hands GGA/RMC to a
:class:`~bench.ground_truth.gps.GpsReader` and ``$PASHR`` to an
:class:`~bench.ground_truth.attitude.AttitudeReader` that share one
:class:`~bench.ground_truth.utc.DayTracker` (so attitudes get the RMC date) and one
``stats`` Counter. Other sentences are counted as ``ignored``.
"""

from __future__ import annotations

from datetime import datetime

from .attitude import Attitude, AttitudeReader
from .gps import GpsFix, GpsReader
from .lines import DEFAULT_MAX_LINE, SentenceReader
from .nmea import sentence_type
from .utc import DayTracker

Record = GpsFix | Attitude


class GroundTruthReader(SentenceReader):
    """``feed(bytes) -> list[GpsFix | Attitude]`` in stream order; never raises on data."""

    def __init__(self, *, start: datetime | None = None, max_line: int = DEFAULT_MAX_LINE) -> None:
        super().__init__(tracker=DayTracker(start), max_line=max_line)
        self.gps = GpsReader(tracker=self.tracker, stats=self.stats)
        self.attitude = AttitudeReader(tracker=self.tracker, stats=self.stats)

    def handle_line(self, line: bytes) -> Record | None:
        reader = self.attitude if sentence_type(line) == b"PASHR" else self.gps
        return reader.handle_line(line)
