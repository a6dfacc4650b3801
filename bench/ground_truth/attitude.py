"""Streaming attitude reader: ``$PASHR`` (OxTS / Applanix layout) -> :class:`Attitude`.

Layout, conventions and units are those of :mod:`emulator.truth.nmea` and
:mod:`emulator.frames.attitude`: heading degrees true clockwise from north, pitch
positive nose up, roll positive right side down (intrinsic Z-Y-X on NED / FRD). Each
record also carries the equivalent quaternion ``[w, x, y, z]`` rotating our body frame
(x forward, y left, z up) into ENU, ready for the export table.

Only the attitude form is read: the sentence whose third field is ``T`` (true heading).
Ashtech's other ``$PASHR,<id>,...`` sentences (POS, SAT, RID, ACK, ...) and every other
sentence type are ``ignored``; binary data, bad checksums and malformed fields are
counted as in :mod:`.gps`. Counters added here: ``pashr`` and ``attitudes`` (records
emitted).

A record's ``utc`` is dated through a shared :class:`~bench.ground_truth.utc.DayTracker`
(the GPS reader's RMC dates, or a start datetime you give it); None until a date is known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, time

from pynmeagps import NMEAMessage

from emulator.frames.attitude import hpr_to_quaternion

from .lines import SentenceReader
from .nmea import PLAIN_NUMBER, FieldError, sentence_type, time_of_day


@dataclass(frozen=True, slots=True)
class Attitude:
    """One attitude (``$PASHR``, or MAVLink via :mod:`.mavlink`). Degrees and metres; None
    where a field was empty or the source has no such field."""

    time_of_day: time | None  # UTC
    utc: datetime | None  # aware UTC; None until a date is known
    heading: float  # degrees true, clockwise from north
    roll: float  # degrees, positive right side down
    pitch: float  # degrees, positive nose up
    quaternion: tuple[float, float, float, float]  # [w, x, y, z], FLU body -> ENU, w >= 0
    heave: float | None = None  # metres, positive up
    roll_accuracy: float | None = None  # 1-sigma degrees
    pitch_accuracy: float | None = None
    heading_accuracy: float | None = None
    gps_quality: int | None = None  # 0 no position, 1 non-RTK, 2 RTK
    ins_status: int | None = None  # 0 not aligned, 1 aligned
    time_boot_ms: int | None = None  # MAVLink only: the autopilot's clock


def _number(raw: str, required: bool) -> float | None:
    if raw == "":
        if required:
            raise FieldError("missing angle")
        return None
    if not PLAIN_NUMBER.match(raw):
        raise FieldError(raw)
    value = float(raw)
    if not math.isfinite(value):
        raise FieldError(raw)
    return value


def _flag(raw: str) -> int | None:
    if raw == "":
        return None
    if not raw.isdigit() or len(raw) > 3:
        raise FieldError(raw)
    return int(raw)


class AttitudeReader(SentenceReader):
    """``feed(bytes) -> list[Attitude]``; never raises on data, memory bounded."""

    def accepts(self, line: bytes) -> bool:
        fields = line.split(b",", 4)
        return sentence_type(line) == b"PASHR" and len(fields) >= 4 and fields[3] == b"T"

    def decode(self, msg: NMEAMessage, line: bytes) -> Attitude:
        # We read the raw fields: pynmeagps types them (DE/IN) but we want a strict
        # number syntax and None for empty fields. Its parse verified the checksum.
        p = list(msg.payload) + [""] * max(0, 11 - len(msg.payload))
        if len(msg.payload) > 11:
            raise FieldError("too many fields")
        tod = time_of_day(msg, "utctime", p[0], self.stats)
        heading, roll, pitch = (_number(p[i], required=True) for i in (1, 3, 4))  # floats: required
        if not (0.0 <= heading <= 360.0 and -180.0 <= roll <= 180.0 and -90.0 <= pitch <= 90.0):
            raise FieldError("angle out of range")
        q = tuple(float(c) for c in hpr_to_quaternion(heading, roll, pitch))
        utc = self.tracker.resolve(tod)
        heave, roll_accuracy, pitch_accuracy, heading_accuracy = (_number(f, required=False) for f in p[5:9])
        att = Attitude(tod, utc, heading, roll, pitch, q, heave, roll_accuracy, pitch_accuracy,
                       heading_accuracy, gps_quality=_flag(p[9]), ins_status=_flag(p[10]))
        self.stats["pashr"] += 1
        self.stats["attitudes"] += 1
        return att
