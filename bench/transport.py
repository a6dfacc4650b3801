"""Opening any device the bench reads: one mechanism, pyserial's URL handlers.

A device argument is a path (``/dev/ttyUSB0``) or a pyserial URL: pyserial's own
(``loop://``, ``socket://``, ``spy://``, ``cp2110://`` over hidapi), ours ``usb://``
(pyusb endpoints, :mod:`bench.urlhandler`) and the emulator's ``arvaemu://``
(:mod:`emulator.urlhandler`). Importing this module registers both packages in
``serial.protocol_handler_packages``; there is no transport layer beside pyserial's.
"""

from __future__ import annotations

import serial

import bench.urlhandler  # noqa: F401  (registers usb://)
import emulator.urlhandler  # noqa: F401  (registers arvaemu://)


def open_device(url: str, baudrate: int = 115200, timeout: float | None = 0.1, **options) -> serial.SerialBase:
    """``serial.serial_for_url`` with our handlers registered; errors propagate as
    pyserial raises them (``serial.SerialException``)."""
    return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, **options)
