"""Sources that can never be read, refused before ``dash`` or ``log`` starts (issue 16).

The dashboard and the logger retry a device that is missing or fails (it may be plugged
in later), so a source that can *never* work would otherwise redraw "reopening" or log
nothing for ever. These are refused up front, as one :class:`InputError` line (exit 2):

* a URL whose scheme no pyserial handler knows (``bogus://x``) or whose extra is missing;
* an ``arvaemu://`` URL whose scene is missing or does not validate, or whose options are
  wrong (the port is opened once, in-process, and closed: no side effect);
* a regular file with no valid ``$PARVA`` sentence in its first :data:`SNIFF_BYTES`.

Paths that do not exist (yet) and reachable-later URLs (``socket://``, ``rfc2217://``)
are left to the retry loop, as before.
"""

from __future__ import annotations

import importlib
import os
import stat

import serial

from firmware_proto.decoder import Decoder
from firmware_proto.errors import InputError

from .transport import check_url, open_device

#: Bytes of a regular file read to find one valid sentence.
SNIFF_BYTES = 64 * 1024


def _scheme_known(scheme: str) -> bool:
    for package in serial.protocol_handler_packages:
        try:
            importlib.import_module(f"{package}.protocol_{scheme}")
        except ImportError:
            continue
        return True
    return False


def check_source(url: str, kind: str = "arva", command: str = "dash") -> None:
    """:class:`InputError` if ``url`` can never deliver data (see the module docstring)."""
    scheme, sep, _ = url.partition("://")
    if sep:
        check_url(url)  # MissingExtra for usb:// / cp2110:// without their extra
        if not scheme or not _scheme_known(scheme.lower()):
            raise InputError(f"{command}: {url}: unknown URL scheme {scheme!r}")
        if scheme.lower() == "arvaemu":
            try:
                open_device(url, timeout=0).close()
            except (serial.SerialException, ValueError) as exc:
                raise InputError(f"{command}: {exc}") from None
        return
    try:
        st = os.stat(url)
    except OSError:
        return  # missing (yet) or not accessible: the retry loop reports and retries it
    if stat.S_ISREG(st.st_mode) and kind == "arva":
        try:
            with open(url, "rb") as f:
                head = f.read(SNIFF_BYTES)
        except OSError as exc:
            raise InputError(f"{command}: {url}: cannot read: {exc.strerror or exc}") from None
        dec = Decoder()
        dec.feed(head)
        dec.flush()
        if dec.stats.sentences_ok == 0:
            raise InputError(f"{command}: {url}: no valid $PARVA sentence in the first {len(head)} bytes")


def check_sources(specs, command: str) -> None:
    """:func:`check_source` for every device spec (``.url``, ``.kind``); ``command`` names
    the sub-command in the message."""
    for spec in specs:
        check_source(spec.url, spec.kind, command)
