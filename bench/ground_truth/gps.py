"""Streaming GPS reader: NMEA 0183 GGA, RMC and GLL from any talker -> :class:`GpsFix` records.

``GpsReader().feed(chunk)`` accepts any bytes in any chunking and returns one
:class:`GpsFix` per checksum-verified GGA, RMC or GLL sentence (GP, GN, GL, GA, BD/GB,
GQ, ... talkers), with or without a position: a receiver without a fix still reports that
it is alive. Records are not merged across sentences (a GGA and an RMC of one epoch are
two records with the same ``utc``). GLL (position and time, no date, no altitude) is read
because some Garmins send an extra GLL fix between their GGA/RMC pairs. Degrees (north /
east positive, as pynmeagps parses them, rounded to 1e-10), metres, knots:

* ``alt_hae = alt_msl + geoid_sep`` (GGA's height above the WGS-84 ellipsoid, the one
  :mod:`emulator.frames.geodesy` uses) when both are sent, else None: receivers that leave
  the separation empty may put the ellipsoid height in the MSL field, and we have no geoid
  model to tell.
* ``utc`` (aware) is dated by a :class:`~bench.ground_truth.utc.DayTracker`: RMC's own
  date, GGA's and GLL's by the last date seen; ``ZDA`` (time and date, no position: some
  receivers send GGA + ZDA and no RMC) only sets that date. None until a date is known.
* ``valid``: GGA quality > 0, or RMC/GLL status ``A`` with an FAA mode other than ``N``
  (dead reckoning counts; ``quality`` / ``mode`` says what it is).

Everything else is skipped and counted in ``stats``: the keys of :mod:`.lines` and
:mod:`.nmea`, ``ignored`` (other sentence types), ``gga``, ``rmc``, ``gll``, ``zda``,
``fixes``, ``no_position`` and ``leap_second`` (23:59:60, which a datetime cannot hold).
A non-empty field that does not parse (time, date, latitude beyond 90, minutes >= 60, a
hemisphere other than N/S/E/W) makes the sentence ``malformed``, except an invalid
position in a sentence that itself says "no fix" (GGA quality 0, RMC/GLL status V or mode
N): a receiver's placeholder (``8960.000000,N``), kept without a position and counted as
``placeholder_position``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import date, datetime, time

from pynmeagps import NMEAMessage

from .lines import SentenceReader
from .nmea import PLAIN_NUMBER, FieldError, sentence_type, talker_of, time_of_day, typed_value

_DATE = re.compile(r"\d{6}\Z")
_LAT = re.compile(r"\d{4}(\.\d+)?\Z")
_LON = re.compile(r"\d{5}(\.\d+)?\Z")


@dataclass(frozen=True, slots=True)
class GpsFix:
    """One GGA, RMC or GLL sentence. Degrees, metres, knots; None where the sentence had nothing."""

    sentence: str  # "GGA", "RMC" or "GLL"
    talker: str  # "GP", "GN", "BD", ...
    time_of_day: time | None  # UTC
    utc: datetime | None  # aware UTC; None until a date is known
    lat: float | None
    lon: float | None
    alt_msl: float | None = None  # GGA: above mean sea level, m
    geoid_sep: float | None = None  # GGA: geoid above ellipsoid, m
    alt_hae: float | None = None  # alt_msl + geoid_sep: above the WGS-84 ellipsoid, m
    quality: int | None = None  # GGA fix quality 0-8
    sats: int | None = None  # GGA satellites used
    hdop: float | None = None  # GGA
    status: str | None = None  # RMC/GLL 'A' valid / 'V' warning
    mode: str | None = None  # RMC/GLL FAA mode indicator (NMEA >= 2.3): A D E F M N P R S
    speed_knots: float | None = None  # RMC speed over ground
    course: float | None = None  # RMC course over ground, degrees true

    @property
    def valid(self) -> bool:
        """Whether the receiver says this position is a fix (see the module docstring)."""
        if self.lat is None or self.lon is None:
            return False
        if self.sentence == "GGA":
            return bool(self.quality)
        return self.status == "A" and self.mode != "N"


def _raw(msg: NMEAMessage, index: int) -> str:
    payload = msg.payload
    return payload[index] if index < len(payload) else ""


def _lat_lon(msg: NMEAMessage, i: int) -> tuple[float | None, float | None]:
    """Position from payload fields i..i+3 (lat, N/S, lon, E/W), validated."""
    lat_s, ns, lon_s, ew = (_raw(msg, k) for k in range(i, i + 4))
    if lat_s == "" and lon_s == "":
        return None, None
    if not (_LAT.match(lat_s) and _LON.match(lon_s)) or ns not in ("N", "S") or ew not in ("E", "W"):
        raise FieldError("lat/lon")
    if float(lat_s[2:]) >= 60.0 or float(lon_s[3:]) >= 60.0:
        raise FieldError("minutes")
    lat, lon = getattr(msg, "lat", ""), getattr(msg, "lon", "")
    if not isinstance(lat, float) or not isinstance(lon, float) or abs(lat) > 90.0 or abs(lon) > 180.0:
        raise FieldError("lat/lon")
    return lat, lon


def _number(msg: NMEAMessage, name: str, index: int, kind: type = float) -> float | int | None:
    """Field ``index`` (named ``name`` by pynmeagps) as a ``kind``: digits only for an int,
    a plain decimal number for a float (float() would take "nan", "inf", "1e5")."""
    raw = _raw(msg, index)
    if raw and not (raw.isdigit() if kind is int else PLAIN_NUMBER.match(raw)):
        raise FieldError(name)
    value = typed_value(msg, name, raw)
    return None if value is None else kind(value)


class GpsReader(SentenceReader):
    """``feed(bytes) -> list[GpsFix]``; never raises on data, memory bounded. A shared
    ``tracker`` gives an attitude reader on the same stream the RMC date."""

    def accepts(self, line: bytes) -> bool:
        return sentence_type(line) in (b"GGA", b"RMC", b"GLL", b"ZDA") and line[1:3].isalpha()

    def decode(self, msg: NMEAMessage, line: bytes) -> GpsFix | None:
        kind = sentence_type(line)
        if kind == b"ZDA":
            self._zda(msg)
            return None
        fix = (self._gga if kind == b"GGA" else self._rmc if kind == b"RMC" else self._gll)(msg, line)
        self.stats[fix.sentence.lower()] += 1
        self.stats["fixes"] += 1
        if fix.lat is None:
            self.stats["no_position"] += 1
        return fix

    def _gga(self, msg: NMEAMessage, line: bytes) -> GpsFix:
        # payload: 0 time, 1-4 lat N lon E, 5 quality, 6 sats, 7 hdop, 8 alt, 9 M, 10 sep, 11 M
        tod = time_of_day(msg, "time", _raw(msg, 0), self.stats)
        quality = _number(msg, "quality", 5, int)
        lat, lon = self._position(msg, 1, fix_claimed=bool(quality))
        alt_msl = _number(msg, "alt", 8)
        sep = _number(msg, "sep", 10)
        utc = self.tracker.resolve(tod)
        return GpsFix("GGA", talker_of(line), tod, utc, lat, lon, alt_msl=alt_msl, geoid_sep=sep,
                      alt_hae=None if alt_msl is None or sep is None else alt_msl + sep,
                      quality=quality, sats=_number(msg, "numSV", 6, int), hdop=_number(msg, "HDOP", 7))

    def _rmc(self, msg: NMEAMessage, line: bytes) -> GpsFix:
        # payload: 0 time, 1 status, 2-5 lat N lon E, 6 speed, 7 course, 8 date, 9-10 magvar, 11 mode
        tod = time_of_day(msg, "time", _raw(msg, 0), self.stats)
        status = _raw(msg, 1) or None
        mode = _raw(msg, 11) or None
        lat, lon = self._position(msg, 2, fix_claimed=status == "A" and mode != "N")
        raw_date = _raw(msg, 8)
        day = None
        if raw_date:
            if not _DATE.match(raw_date):
                raise FieldError("date")
            day = typed_value(msg, "date", raw_date)
            assert isinstance(day, date)
        utc = self.tracker.anchor(day, tod) if tod is not None and day is not None else self.tracker.resolve(tod)
        return GpsFix("RMC", talker_of(line), tod, utc, lat, lon, status=status, mode=mode,
                      speed_knots=_number(msg, "spd", 6), course=_number(msg, "cog", 7))

    def _gll(self, msg: NMEAMessage, line: bytes) -> GpsFix:
        # payload: 0-3 lat N lon E, 4 time, 5 status, 6 mode (NMEA >= 2.3; older: absent)
        if len(msg.payload) > 7:
            raise FieldError("too many fields")
        tod = time_of_day(msg, "time", _raw(msg, 4), self.stats)
        status = _raw(msg, 5) or None
        mode = _raw(msg, 6) or None
        lat, lon = self._position(msg, 0, fix_claimed=status == "A" and mode != "N")
        utc = self.tracker.resolve(tod)
        return GpsFix("GLL", talker_of(line), tod, utc, lat, lon, status=status, mode=mode)

    def _position(self, msg: NMEAMessage, index: int, fix_claimed: bool) -> tuple[float | None, float | None]:
        """Validated position, or a placeholder dropped when the sentence says there is no
        fix (see the module docstring; also 36000.0000,N)."""
        try:
            return _lat_lon(msg, index)
        except FieldError:
            if fix_claimed:
                raise
            self.stats["placeholder_position"] += 1
            return None, None

    def _zda(self, msg: NMEAMessage) -> None:
        """ZDA (time and date, no position) only dates what follows: no record."""
        # payload: 0 time, 1 day, 2 month, 3 four-digit year, 4-5 local zone
        tod = time_of_day(msg, "time", _raw(msg, 0), self.stats)
        parts = [_raw(msg, k) for k in (1, 2, 3)]
        if tod is None and parts == ["", "", ""]:
            self.stats["zda"] += 1
            return  # a receiver that does not know the time yet
        if tod is None or not all(p.isdigit() for p in parts) or len(parts[2]) != 4:
            raise FieldError("zda")
        day, month, year = (int(p) for p in parts)
        self.tracker.anchor(date(year, month, day), tod)  # ValueError for 31 Feb: malformed
        self.stats["zda"] += 1
