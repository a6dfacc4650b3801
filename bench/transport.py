"""Opening any device the bench reads: one mechanism, pyserial's URL handlers.

A device argument is a path (``/dev/ttyUSB0``) or a pyserial URL: pyserial's own
(``loop://``, ``socket://``, ``spy://``, ``cp2110://`` over hidapi), ours ``usb://``
(pyusb endpoints, :mod:`bench.urlhandler`) and the emulator's ``arvaemu://``
(:mod:`emulator.urlhandler`). Importing this module registers both packages in
``serial.protocol_handler_packages``; there is no transport layer beside pyserial's.
"""

from __future__ import annotations

import importlib

import serial

from firmware_proto.errors import MissingExtra

import bench.urlhandler  # noqa: F401  (registers usb://)
import emulator.urlhandler  # noqa: F401  (registers arvaemu://)


#: URL schemes whose handler needs an extra: scheme -> (module, package, extra). pyserial
#: skips a handler that fails to import and then calls the scheme "not known", which
#: would send a user hunting for a typo instead of a missing package.
EXTRA_SCHEMES = {"cp2110": ("hid", "hidapi", "hid"), "usb": ("usb.core", "pyusb", "usb")}


def check_url(url: str) -> None:
    """:class:`MissingExtra` if ``url``'s scheme needs an extra that is not installed."""
    scheme, sep, _ = url.partition("://")
    need = EXTRA_SCHEMES.get(scheme.lower()) if sep else None
    if need is None:
        return
    module, package, extra = need
    try:
        importlib.import_module(module)
    except ImportError:
        raise MissingExtra(f"a {scheme.lower()}:// device", package, extra) from None


def open_device(url: str, baudrate: int = 115200, timeout: float | None = 0.1, keep_input: bool = False,
                **options) -> serial.SerialBase:  # fmt: skip
    """``serial.serial_for_url`` with our handlers registered; :class:`MissingExtra` for a
    scheme whose extra is missing; other errors propagate as pyserial raises them
    (``serial.SerialException``, ``ValueError``).

    ``keep_input``: pyserial discards what the OS has already buffered when it opens a port
    (posix ``tcflush``, ``socket://`` reads and drops); a reconnecting logger wants those
    bytes (they arrived during the outage), so the flush is skipped for this open."""
    check_url(url)
    if not keep_input:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, **options)
    port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, do_not_open=True, **options)
    shadowed = [name for name in ("reset_input_buffer", "_reset_input_buffer") if hasattr(port, name)]
    for name in shadowed:  # instance attributes shadow the methods during open() only
        setattr(port, name, _keep)
    try:
        port.open()
    finally:
        for name in shadowed:
            delattr(port, name)
    return port


def _keep() -> None:
    """Stands in for pyserial's input flush while a port opens (see ``keep_input``)."""
