"""Ground-truth readers: GPS (NMEA GGA/RMC) and attitude ($PASHR, MAVLink) from real devices.

Streaming and tolerant: ``feed(bytes)`` in any chunking returns frozen records; unknown
sentences, binary data, bad checksums and garbage are skipped and counted in ``stats``,
never raised, and memory stays bounded. Modules: ``lines`` (bytes to ``$...`` lines),
``nmea`` (a line to a checked message), ``utc`` (dating across midnight), ``gps``,
``attitude``, ``mavlink`` (the ``mavlink`` extra, imported on use, not here); and here
:class:`GroundTruthReader`, GPS and attitude on one stream.
"""

from __future__ import annotations

from datetime import datetime

from .attitude import Attitude, AttitudeReader
from .gps import GpsFix, GpsReader
from .lines import DEFAULT_MAX_LINE, LineSplitter, SentenceReader
from .nmea import sentence_type
from .utc import DayTracker

__all__ = ["DEFAULT_MAX_LINE", "Attitude", "AttitudeReader", "DayTracker", "GpsFix", "GpsReader",
           "GroundTruthReader", "LineSplitter"]


class GroundTruthReader(SentenceReader):
    """One stream carrying both GPS and attitude (an INS such as the OxTS in gpsd's
    rst39.log): ``feed(bytes) -> list[GpsFix | Attitude]`` in stream order; never raises
    on data. The bytes are split once; GGA/RMC go to a :class:`GpsReader` and ``$PASHR``
    to an :class:`AttitudeReader` sharing one :class:`DayTracker` (so attitudes get the
    RMC date) and one ``stats`` Counter. Other sentences are counted as ``ignored``."""

    def __init__(self, *, start: datetime | None = None, max_line: int = DEFAULT_MAX_LINE) -> None:
        super().__init__(tracker=DayTracker(start), max_line=max_line)
        self.gps = GpsReader(tracker=self.tracker, stats=self.stats)
        self.attitude = AttitudeReader(tracker=self.tracker, stats=self.stats)

    def handle_line(self, line: bytes) -> GpsFix | Attitude | None:
        reader = self.attitude if sentence_type(line) == b"PASHR" else self.gps
        return reader.handle_line(line)
