"""Generate ground-truth sentences a real GPS and attitude unit would send, from poses.

* GPS: NMEA 0183 ``GGA`` + ``RMC`` (``gga_sentence``, ``rmc_sentence``, and ``gps_sentences``
  for both).
* Attitude: ``$PASHR`` in the OxTS / Applanix layout (``pashr_sentence``,
  ``pashr_from_quaternion``, and ``pashr_from_quaternions`` for a batch)::

      $PASHR,hhmmss.sss,HHH.HH,T,+RR.RR,+PP.PP,+hh.hh,r.rrr,p.ppp,h.hhh,Q,I*CS
              UTC time   heading   roll   pitch  heave  sigma roll/pitch/heading  GPS quality, INS status

  heading in degrees true [0, 360), 'T' = true, roll and pitch in degrees, heave in
  metres (positive up), the three 1-sigma accuracies in degrees, GPS quality flag
  (0 no position, 1 non-RTK fix, 2 RTK) and INS status flag (0 not aligned, 1 aligned).
  Angles follow :mod:`emulator.frames.attitude` (heading clockwise from true north,
  pitch positive nose up, roll positive right side down; intrinsic Z-Y-X on NED/FRD).

Every sentence is assembled by ``pynmeagps.NMEAMessage(talker, msgID, GET, payload=...)``
(a self-check of each field, and the checksum) from field strings formatted here;
precision and why we format the fields ourselves: docs/emulator.md "Sentence format and
precision". Latitude and longitude in degrees, altitude in metres above the WGS-84
ellipsoid, velocities ENU in m/s, speed in knots, course in degrees true.

Timestamps: an aware datetime is converted to UTC; a naive one is taken as UTC.
Bad arguments raise :class:`~firmware_proto.errors.InputError` naming the argument.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timedelta, timezone
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pynmeagps import NMEAMessage
from pynmeagps.nmeatypes_core import GET

from firmware_proto.errors import InputError, PoseError

from emulator.frames.attitude import quaternion_to_hpr, wrap_heading

#: 1 knot = 1852 m / 3600 s exactly.
KNOTS_PER_MPS = 3600.0 / 1852.0

_FAA_MODES = frozenset("ADEFMNPRS")


# ---------------------------------------------------------------------------- field checks
def _number(value: object, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{field}: must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{field}: must be finite")
    return v


def _integer(value: object, field: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{field}: must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise InputError(f"{field}: {value} is outside [{lo}, {hi}]")
    return int(value)


def _talker(talker: str) -> str:
    if not (isinstance(talker, str) and len(talker) == 2 and talker.isascii() and talker.isalpha() and talker.isupper()):
        raise InputError(f"talker: must be two upper-case letters (GP, GN, ...), got {talker!r}")
    return talker


def _utc(value: datetime, unit_us: int) -> datetime:
    """``value`` in UTC, rounded half-up to a multiple of ``unit_us`` microseconds."""
    if not isinstance(value, datetime):
        raise InputError(f"utc: must be a datetime, got {value!r}")
    t = value.replace(tzinfo=timezone.utc) if value.tzinfo is None else value.astimezone(timezone.utc)
    us = t.microsecond
    rounded = (us + unit_us // 2) // unit_us * unit_us
    return t.replace(microsecond=0) + timedelta(microseconds=rounded)


def _hhmmss(t: datetime, decimals: int) -> str:
    frac = t.microsecond // 10 ** (6 - decimals)
    return f"{t.hour:02d}{t.minute:02d}{t.second:02d}.{frac:0{decimals}d}"


def _dmm(value: float, degree_digits: int, decimals: int, hemispheres: str) -> tuple[str, str]:
    """(d)ddmm.mmm... and hemisphere letter, rounded half-up in integer arc-minute units.

    Rounding the whole value first means 44.99999999999 prints as 4500.0000000, never as
    the invalid 4460.0000000.
    """
    scale = 10**decimals
    units = math.floor(abs(value) * 60.0 * scale + 0.5)
    degrees, rest = divmod(units, 60 * scale)
    minutes, frac = divmod(rest, scale)
    text = f"{degrees:0{degree_digits}d}{minutes:02d}"
    if decimals:
        text += f".{frac:0{decimals}d}"
    hemisphere = hemispheres[1] if value < 0 and units else hemispheres[0]
    return text, hemisphere


def _position(lat: float | None, lon: float | None, decimals: int) -> list[str]:
    if lat is None and lon is None:
        return ["", "", "", ""]
    if lat is None or lon is None:
        raise InputError("lat/lon: give both or neither")
    lat_f, lon_f = _number(lat, "lat"), _number(lon, "lon")
    if not -90.0 <= lat_f <= 90.0:
        raise InputError(f"lat: {lat_f} is outside [-90, 90] degrees")
    if not -180.0 <= lon_f <= 180.0:
        raise InputError(f"lon: {lon_f} is outside [-180, 180] degrees")
    if not (isinstance(decimals, int) and 0 <= decimals <= 9):
        raise InputError(f"lat_lon_decimals: must be an integer in [0, 9], got {decimals!r}")
    la, ns = _dmm(lat_f, 2, decimals, "NS")
    lo, ew = _dmm(lon_f, 3, decimals, "EW")
    return [la, ns, lo, ew]


def _fixed(value: float, decimals: int, short: bool) -> str:
    """``value`` with ``decimals`` decimals, or (``short``) without trailing zeros beyond
    the first decimal."""
    text = f"{value:.{decimals}f}"
    if short and "." in text:
        text = text.rstrip("0")
        text += "0" if text.endswith(".") else ""
    return text


# ---------------------------------------------------------------------------- GPS
def speed_course_from_enu(v_east: float, v_north: float) -> tuple[float, float | None]:
    """(speed over ground in knots, course over ground in degrees true [0, 360) or None).

    The course is None for zero horizontal speed, where it is undefined.
    """
    ve, vn = _number(v_east, "velocity.east"), _number(v_north, "velocity.north")
    speed = math.hypot(ve, vn)
    if speed == 0.0:
        return 0.0, None
    return speed * KNOTS_PER_MPS, float(wrap_heading(math.degrees(math.atan2(ve, vn))))


def gga_sentence(
    utc: datetime, lat: float | None, lon: float | None, alt: float | None, *,
    geoid_sep: float = 0.0, quality: int = 1, sats: int = 12, hdop: float = 0.8,
    talker: str = "GP", lat_lon_decimals: int = 7, short: bool = False,
) -> bytes:
    """One ``$xxGGA`` sentence (bytes, CR LF terminated).

    ``short``: HDOP and the geoid separation with the fewest decimals that keep their
    value (``0.8``, ``48.25``), which keeps a GGA within NMEA's 82 characters (the
    emulator's streams use it; docs/emulator.md "Sentence format and precision").

    ``lat``/``lon`` in degrees, ``alt`` in metres above the WGS-84 ellipsoid; the sentence
    carries MSL = alt - geoid_sep and the separation. ``quality``: 0 no fix, 1 GPS,
    2 DGPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning, ... (0-8). Give ``lat = lon =
    alt = None`` (with ``quality=0``) for a receiver without a fix: the fields are empty.
    """
    t = _utc(utc, 10_000)
    q = _integer(quality, "quality", 0, 8)
    n_sats = _integer(sats, "sats", 0, 99)
    h = _number(hdop, "hdop")
    if h < 0.0:
        raise InputError(f"hdop: must be >= 0, got {h}")
    sep = _number(geoid_sep, "geoid_sep")
    fields = [_hhmmss(t, 2), *_position(lat, lon, lat_lon_decimals), str(q), f"{n_sats:02d}", _fixed(h, 2, short)]
    if alt is None:
        fields += ["", "", "", ""]
    else:
        fields += [f"{_number(alt, 'alt') - sep:.3f}", "M", _fixed(sep, 3, short), "M"]
    fields += ["", ""]  # age of differential corrections, reference station id
    return NMEAMessage(_talker(talker), "GGA", GET, payload=fields).serialize()


def rmc_sentence(
    utc: datetime, lat: float | None, lon: float | None, *,
    velocity_enu: ArrayLike | None = None, speed_knots: float | None = None, course: float | None = None,
    valid: bool = True, mode: str = "A", talker: str = "GP", lat_lon_decimals: int = 7,
) -> bytes:
    """One ``$xxRMC`` sentence (NMEA 2.3 layout, with the FAA mode indicator).

    Speed and course come from ``velocity_enu`` (m/s; the vertical part is ignored) or,
    if it is None, from ``speed_knots`` / ``course`` (degrees true) as given, empty when
    None. ``valid=False`` prints status ``V`` and mode ``N`` whatever ``mode`` says.
    ``mode`` is the FAA indicator: A autonomous, D differential, E estimated, F RTK float,
    R RTK fixed, N not valid, ...
    """
    t = _utc(utc, 10_000)
    if velocity_enu is not None:
        v = np.asarray(velocity_enu, dtype=np.float64).reshape(-1)
        if v.size not in (2, 3):
            raise InputError(f"velocity_enu: needs [east, north] or [east, north, up], got {v.size} values")
        speed, cog = speed_course_from_enu(v[0], v[1])
    else:
        speed = None if speed_knots is None else _number(speed_knots, "speed_knots")
        cog = None if course is None else float(wrap_heading(_number(course, "course")))
    if speed is not None and speed < 0.0:
        raise InputError(f"speed_knots: must be >= 0, got {speed}")
    if not (isinstance(mode, str) and len(mode) == 1 and mode in _FAA_MODES):
        raise InputError(f"mode: must be one FAA mode letter of {''.join(sorted(_FAA_MODES))}, got {mode!r}")
    status, faa = ("A", mode) if valid else ("V", "N")
    fields = [_hhmmss(t, 2), status, *_position(lat, lon, lat_lon_decimals),
              "" if speed is None else f"{speed:.3f}", "" if cog is None else _degrees_true(cog, 1),
              f"{t.day:02d}{t.month:02d}{t.year % 100:02d}",
              "", "", faa]  # no magnetic variation: ground truth is true north only
    return NMEAMessage(_talker(talker), "RMC", GET, payload=fields).serialize()


def _degrees_true(angle: float, digits: int) -> str:
    """``angle`` to 0.01 deg in [0, 360), at least ``digits`` before the point."""
    hundredths = math.floor(angle * 100.0 + 0.5) % 36000  # 359.996 prints as 0.00, not 360.00
    return f"{hundredths // 100:0{digits}d}.{hundredths % 100:02d}"


def gps_sentences(
    utc: datetime, lat: float, lon: float, alt: float, *, velocity_enu: ArrayLike | None = None,
    quality: int = 1, talker: str = "GP", lat_lon_decimals: int = 7, **gga_options: Any,
) -> bytes:
    """RMC then GGA for one epoch, the order u-blox receivers use: a reader starting on
    this stream dates the GGA with the RMC's date at once. The RMC's FAA mode follows
    ``quality`` (2 -> D, 4 -> R, 5 -> F, 6 -> E, ...); ``velocity_enu`` None means at rest.
    ``gga_options``: the GGA's other options (``geoid_sep``, ``sats``, ``hdop``, ``short``: see
    :func:`gga_sentence`)."""
    mode = {0: "N", 2: "D", 4: "R", 5: "F", 6: "E", 7: "M", 8: "S"}.get(quality, "A")
    rmc = rmc_sentence(
        utc, lat, lon, velocity_enu=velocity_enu if velocity_enu is not None else (0.0, 0.0),
        valid=quality != 0, mode=mode, talker=talker, lat_lon_decimals=lat_lon_decimals,
    )
    gga = gga_sentence(utc, lat, lon, alt, quality=quality, talker=talker, lat_lon_decimals=lat_lon_decimals, **gga_options)
    return rmc + gga


# ---------------------------------------------------------------------------- attitude
def _signed(value: float, field: str) -> str:
    return f"{_number(value, field):+06.2f}"


def _accuracy(value: float | None, field: str) -> str:
    if value is None:
        return ""
    v = _number(value, field)
    if v < 0.0:
        raise InputError(f"{field}: must be >= 0, got {v}")
    return f"{v:.3f}"


def pashr_sentence(
    utc: datetime, heading: float, roll: float, pitch: float, *, heave: float = 0.0,
    roll_accuracy: float | None = 0.05, pitch_accuracy: float | None = 0.05, heading_accuracy: float | None = 0.1,
    gps_quality: int = 1, ins_status: int = 1,
) -> bytes:
    """One ``$PASHR`` sentence (layout in the module docstring), angles in degrees.

    ``heading`` is wrapped into [0, 360) after rounding to 0.01 deg (359.996 -> 000.00);
    ``roll`` and ``pitch`` print with a sign, as OxTS units do (``+00.39``). Accuracies
    are 1-sigma degrees, None for an empty field.
    """
    t = _utc(utc, 1_000)
    fields = [
        _hhmmss(t, 3), _degrees_true(_number(heading, "heading"), 3), "T",
        _signed(roll, "roll"), _signed(pitch, "pitch"), _signed(heave, "heave"),
        _accuracy(roll_accuracy, "roll_accuracy"), _accuracy(pitch_accuracy, "pitch_accuracy"),
        _accuracy(heading_accuracy, "heading_accuracy"),
        str(_integer(gps_quality, "gps_quality", 0, 9)), str(_integer(ins_status, "ins_status", 0, 9)),
    ]
    return NMEAMessage("P", "ASHR", GET, payload=fields).serialize()


def pashr_from_quaternion(utc: datetime, q: ArrayLike, **kwargs: object) -> bytes:
    """``$PASHR`` for orientation ``q`` = ``[w, x, y, z]`` (FLU body into ENU); see
    :func:`pashr_sentence` for the keyword arguments. A quaternion that cannot be
    normalised raises :class:`~firmware_proto.errors.PoseError` naming ``orientation``."""
    if np.shape(q) != (4,):
        raise PoseError("orientation", f"one quaternion [w, x, y, z] is needed, got shape {np.shape(q)}")
    heading, roll, pitch = quaternion_to_hpr(q)
    return pashr_sentence(utc, float(heading), float(roll), float(pitch), **kwargs)  # type: ignore[arg-type]


def pashr_from_quaternions(utcs: Sequence[datetime], q: ArrayLike, **kwargs: object) -> bytes:
    """``$PASHR`` sentences for N times and N orientations (N, 4), concatenated.

    The same bytes as N calls of :func:`pashr_from_quaternion`, with the angle conversion
    done once for the whole batch (it dominates the cost of a single call).
    """
    q_arr = np.asarray(q, dtype=np.float64)
    if q_arr.ndim != 2 or q_arr.shape[1] != 4 or q_arr.shape[0] != len(utcs):
        raise PoseError("orientation", f"needs shape ({len(utcs)}, 4) for {len(utcs)} times, got {q_arr.shape}")
    heading, roll, pitch = quaternion_to_hpr(q_arr)
    return b"".join(
        pashr_sentence(t, h, r, p, **kwargs)  # type: ignore[arg-type]
        for t, h, r, p in zip(utcs, heading.tolist(), roll.tolist(), pitch.tolist(), strict=True)
    )
