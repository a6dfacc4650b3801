"""Ground-truth readers: GPS (NMEA GGA/RMC) and attitude ($PASHR, MAVLink) from real devices.

Streaming and tolerant: ``feed(bytes)`` in any chunking returns frozen records; unknown
sentences, binary data, bad checksums and garbage are skipped and counted in ``stats``,
never raised, and memory stays bounded. Modules:

* :mod:`.lines` -- bytes to ``$...`` lines (bounded, resynchronising);
* :mod:`.nmea` -- a line to a checksum-verified pynmeagps message;
* :mod:`.utc` -- dating times of day across midnight;
* :mod:`.gps` -- :class:`GpsReader` -> :class:`GpsFix`;
* :mod:`.attitude` -- :class:`AttitudeReader` -> :class:`Attitude`;
* :mod:`.mavlink` -- :class:`MavlinkAttitudeReader`, MAVLink attitude -> :class:`Attitude`
  (the ``mavlink`` extra; imported on use, not here);
* :mod:`.reader` -- :class:`GroundTruthReader`, both on one stream.
"""

from .attitude import Attitude, AttitudeReader
from .gps import GpsFix, GpsReader
from .lines import DEFAULT_MAX_LINE, LineSplitter
from .reader import GroundTruthReader
from .utc import DayTracker

__all__ = ["DEFAULT_MAX_LINE", "Attitude", "AttitudeReader", "DayTracker", "GpsFix", "GpsReader",
           "GroundTruthReader", "LineSplitter"]
