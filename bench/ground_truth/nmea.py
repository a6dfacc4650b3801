"""One complete ``$...`` line -> a checksum-verified pynmeagps message, or a counted reason.

Shared by the GPS and attitude readers. Nothing here raises on any input: pynmeagps is
a third-party parser fed hostile bytes (its field parsing can raise IndexError, ValueError,
its own exception types, ...), so every exception it raises is caught and counted as
``malformed``; our own checks come first so the common failures are classified:

* ``non_ascii``: a byte >= 0x80 or a control character (binary protocol data mostly);
* ``no_checksum``: no ``*hh`` at the end (NMEA makes it optional, but a ground-truth
  reader must not trust unverified bytes);
* ``bad_checksum``: ``*hh`` does not match the XOR of the bytes between ``$`` and ``*``
  (verified by pynmeagps, ``VALCKSUM``);
* ``malformed``: everything else pynmeagps or our field checks reject.
"""

from __future__ import annotations

import re
from collections import Counter
from datetime import time

from pynmeagps import NMEAMessage, NMEAReader
from pynmeagps.exceptions import NMEAParseError
from pynmeagps.nmeatypes_core import GET, VALCKSUM

# Printable ASCII only; '*' followed by exactly two hex digits at the very end.
_PRINTABLE = re.compile(rb"[\x20-\x7e]*\Z")
_TAIL = re.compile(rb"\*[0-9A-Fa-f]{2}\Z")
_TIME = re.compile(r"\d{6}(\.\d{1,6})?\Z")
#: A decimal number as NMEA prints it: optional sign, digits, optional fraction.
PLAIN_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)\Z")


class FieldError(Exception):
    """A field the readers refuse; the sentence is counted as ``malformed``."""


def sentence_type(line: bytes) -> bytes:
    """The address field without the talker: ``GGA`` for ``$GNGGA,...``, ``PASHR`` for
    ``$PASHR,...`` (proprietary sentences keep their ``P`` and manufacturer code)."""
    comma = line.find(b",", 1, 12)
    address = line[1:comma] if comma > 0 else line[1:12].split(b"*", 1)[0]
    if address[:1] == b"P":
        return address
    return address[2:]


def talker_of(line: bytes) -> str:
    """The two-letter talker id (``GP``, ``GN``, ``BD``, ...) of a standard sentence."""
    return line[1:3].decode("ascii", "replace")


def parse_checked(line: bytes, stats: Counter[str]) -> NMEAMessage | None:
    """pynmeagps message of ``line`` (no CR/LF), or None with the reason counted."""
    if not _PRINTABLE.match(line):
        stats["non_ascii"] += 1
        return None
    if not _TAIL.search(line):
        stats["no_checksum"] += 1
        return None
    try:
        msg = NMEAReader.parse(line, msgmode=GET, validate=VALCKSUM)
    except NMEAParseError:
        stats["bad_checksum"] += 1  # the only NMEAParseError parse() raises with VALCKSUM alone
        return None
    except Exception:  # noqa: BLE001 -- see the module docstring
        msg = None
    if msg is None:
        stats["malformed"] += 1
    return msg


def typed_value(msg: NMEAMessage, name: str, raw: str) -> object | None:
    """pynmeagps's typed value of field ``name`` whose text is ``raw``: None if empty;
    FieldError if it has text pynmeagps could not type (it returns "" then, silently)."""
    if raw == "":
        return None
    value = getattr(msg, name, "")
    if value == "":
        raise FieldError(name)
    return value


def time_of_day(msg: NMEAMessage, name: str, raw: str, stats: Counter[str]) -> time | None:
    """UTC time of day of an ``hhmmss[.s...]`` field: None if empty, FieldError if it is
    not exactly that (pynmeagps's strptime would accept ``12345.6``), ``leap_second``
    counted for a second of 60, which a datetime cannot hold."""
    if raw == "":
        return None
    if not _TIME.match(raw):
        raise FieldError(name)
    if raw[4:6] == "60":
        stats["leap_second"] += 1
        raise FieldError(name)
    value = typed_value(msg, name, raw)
    if not isinstance(value, time):
        raise FieldError(name)
    return value
