"""``usb://VID:PID[?serial=S&interface=N&endpoint=0x81&out=0x01&timeout_ms=T]``: a USB endpoint.

A pyserial port over a raw USB device, through pyusb: reads come from a bulk or
interrupt IN endpoint, writes go to a bulk or interrupt OUT endpoint, for devices that
stream bytes over USB without being a serial port or a HID UART bridge. VID and PID are
hexadecimal; the options, and which interface and endpoints are used without them, are
in docs/transports.md ("Notes per transport"). ``timeout_ms`` (default 1000) is the time
limit of one USB transfer; a read waits no longer than the port's ``timeout`` either.

Reads follow pyserial's timeout rules: ``timeout=None`` blocks until ``size`` bytes came,
``timeout=0`` returns what is already there (after a 1 ms poll), ``timeout=T`` waits at
most T seconds. Each transfer asks for exactly one packet (wMaxPacketSize bytes), so a
timed-out transfer never holds data (pyusb drops the bytes of a transfer that times out
half-way); bytes beyond ``size`` are kept for the next read. Baud rate, parity and modem
lines are accepted and ignored. The interface's kernel driver, if any, is detached while
the port is open (Linux). Errors raise ``serial.SerialException``: one line naming the
URL and the reason.
"""

from __future__ import annotations

import contextlib
import errno
import math
import re
import urllib.parse
from dataclasses import dataclass

from serial.serialutil import SerialBase, SerialException, SerialTimeoutException, Timeout, to_bytes

from emulator.output.virtual_line import VirtualLine

#: pyusb backend passed as ``usb.core.find(backend=...)`` (pyusb's documented seam).
#: ``None`` lets pyusb pick libusb1, OpenUSB or libusb0, whichever loads; tests put a
#: fake ``usb.backend.IBackend`` here. ``arva-bench devices`` uses the same one.
BACKEND = None

#: Default time limit of one USB transfer (milliseconds).
DEFAULT_TIMEOUT_MS = 1000
#: Time limit of a poll (milliseconds). libusb reads 0 as "no time limit", so a poll
#: that must not block is the shortest non-zero transfer.
POLL_MS = 1
#: ``in_waiting`` and ``reset_input_buffer`` stop polling once this much is buffered (bytes).
DRAIN_LIMIT = 1 << 16

OPTIONS = ("endpoint", "interface", "out", "serial", "timeout_ms")
USAGE = "usb://VID:PID[?serial=S&interface=N&endpoint=0x81&out=0x01&timeout_ms=T] with VID and PID in hex"
INSTALL_PYUSB = "pyusb is not installed (install the extra: pip install 'arva-bench[usb]')"
NO_BACKEND = "no libusb backend available: install libusb 1.0, e.g. apt install libusb-1.0-0 or brew install libusb"
UDEV_HINT = "on Linux, a udev rule grants access: see docs/transports.md"

#: Endpoint types that stream bytes: bulk and interrupt (usb.util.ENDPOINT_TYPE_BULK, _INTR).
_STREAMING = (2, 3)
_VID_PID = re.compile(r"([0-9A-Fa-f]{1,4}):([0-9A-Fa-f]{1,4})")


@dataclass(frozen=True)
class UsbUrl:
    """A parsed ``usb://`` URL (addresses and numbers as ints, ``None`` when not given)."""

    vid: int
    pid: int
    serial: str | None = None
    interface: int | None = None
    endpoint: int | None = None
    out: int | None = None
    timeout_ms: int = DEFAULT_TIMEOUT_MS

    @property
    def ids(self) -> str:
        """``vvvv:pppp`` in lowercase hex, as lsusb and udev write it."""
        return f"{self.vid:04x}:{self.pid:04x}"


def parse_url(url: str) -> UsbUrl:
    """Parse a ``usb://`` URL; raise ``SerialException`` (``URL: reason``) when it is not one."""
    parts = urllib.parse.urlsplit(url)
    match = _VID_PID.fullmatch(parts.netloc)
    if parts.scheme != "usb" or match is None or parts.path not in ("", "/") or parts.fragment:
        raise SerialException(f"{url}: expected {USAGE}")
    try:
        pairs = urllib.parse.parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise SerialException(f"{url}: expected {USAGE}") from None
    opt = dict(pairs)  # the last of a repeated option
    for key in opt:
        if key not in OPTIONS:
            raise SerialException(f"{url}: unknown option {key!r} (known: {', '.join(OPTIONS)})")
    if opt.get("serial") == "":
        raise SerialException(f"{url}: serial=: expected a serial number")
    return UsbUrl(
        vid=int(match.group(1), 16),
        pid=int(match.group(2), 16),
        serial=opt.get("serial"),
        interface=_integer(url, opt, "interface", 0, 255, "an interface number 0-255"),
        endpoint=_integer(url, opt, "endpoint", 0x81, 0x8F, "an IN endpoint address 0x81-0x8f"),
        out=_integer(url, opt, "out", 0x01, 0x0F, "an OUT endpoint address 0x01-0x0f"),
        timeout_ms=_integer(url, opt, "timeout_ms", 1, 3_600_000, "a whole number of milliseconds >= 1")
        or DEFAULT_TIMEOUT_MS,
    )


def _integer(url: str, opt: dict[str, str], key: str, low: int, high: int, what: str) -> int | None:
    if key not in opt:
        return None
    with contextlib.suppress(ValueError):
        if low <= (value := int(opt[key], 0)) <= high:
            return value
    raise SerialException(f"{url}: {key}={opt[key]}: expected {what}")


def usb_reason(exc: BaseException) -> str:
    """One line for a pyusb error: its text, plus what to do when access was denied."""
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    if getattr(exc, "errno", None) == errno.EACCES:
        text += f"; {UDEV_HINT}"
    return text


def import_pyusb():  # type: ignore[no-untyped-def]
    """``usb`` with ``usb.core`` and ``usb.util`` loaded; ImportError when pyusb is missing."""
    import usb.core
    import usb.util

    return usb


def read_string(device, index: int) -> str | None:  # type: ignore[no-untyped-def]
    """String descriptor INDEX of pyusb DEVICE, in its first language.

    ``None`` for index 0 (no string) or a device without a language table. Unlike
    ``Device.serial_number``, which turns every failure into "The device has no langid",
    this raises ``usb.core.USBError`` with the real reason (e.g. access denied).
    """
    usb = import_pyusb()
    if not index:
        return None
    langids = usb.util.get_langids(device)
    if not langids:
        return None
    return usb.util.get_string(device, index, langids[0])


def _packet_size(endpoint) -> int:  # type: ignore[no-untyped-def]
    """Largest payload of one transaction of ENDPOINT (bytes): wMaxPacketSize with its
    high-bandwidth multiplier (bits 11-12) applied."""
    size = endpoint.wMaxPacketSize & 0x7FF
    return max(1, size * (1 + ((endpoint.wMaxPacketSize >> 11) & 3)))


class Serial(VirtualLine, SerialBase):
    """pyserial ``Serial`` for ``usb://`` URLs (see the module docstring)."""

    # What open() sets, as class defaults: close() works on a port that never opened.
    _device = _in_ep = _out_ep = _usb = None  # _usb: the pyusb package
    _interface: int | None = None
    _url: UsbUrl | None = None
    _reattach = False

    # -- opening ----------------------------------------------------------------
    def open(self) -> None:
        self._may_open()
        self._url = parse_url(self._port)
        try:
            self._usb = usb = import_pyusb()
        except ImportError:
            raise SerialException(f"{self._port}: {INSTALL_PYUSB}") from None
        self._device = self._find(usb)
        try:
            self._claim(usb)
        except BaseException:
            self._release()
            raise
        self._buffer = bytearray()
        self.is_open = True

    def _fail(self, reason: str) -> SerialException:
        return SerialException(f"{self._port}: {reason}")

    def _find(self, usb):  # type: ignore[no-untyped-def]
        """The device the URL names, opened by pyusb's ``find`` (``custom_match`` picks the serial)."""
        url = self._url
        seen: list[str] = []
        unreadable: list[str] = []

        def serial_matches(device) -> bool:  # type: ignore[no-untyped-def]
            if url.serial is None:
                return True
            try:
                number = read_string(device, device.iSerialNumber)
            except (usb.core.USBError, ValueError, NotImplementedError) as exc:
                unreadable.append(usb_reason(exc))
                number = None
            else:
                if number == url.serial:
                    return True
                seen.append("no serial number" if number is None else repr(number))
            usb.util.dispose_resources(device)  # close the handle reading the string opened
            return False

        try:
            device = usb.core.find(idVendor=url.vid, idProduct=url.pid, custom_match=serial_matches, backend=BACKEND)
        except usb.core.NoBackendError:
            raise self._fail(NO_BACKEND) from None
        except usb.core.USBError as exc:
            raise self._fail(f"cannot list USB devices: {usb_reason(exc)}") from None
        if device is not None:
            return device
        if url.serial is None:
            raise self._fail(f"no USB device {url.ids} found")
        found = [f"connected: {', '.join(seen)}"] if seen else []
        if unreadable:
            found.append(f"{len(unreadable)} whose serial number cannot be read: {unreadable[0]}")
        details = f" ({'; '.join(found)})" if found else ""
        raise self._fail(f"no USB device {url.ids} with serial number {url.serial!r}{details}")

    def _claim(self, usb) -> None:  # type: ignore[no-untyped-def]
        """Pick the interface and endpoints, detach the kernel driver, claim the interface."""
        url, device = self._url, self._device
        try:
            try:
                config = device.get_active_configuration()
            except usb.core.USBError as exc:
                if exc.errno is not None:
                    raise
                device.set_configuration()  # unconfigured device: take its first configuration
                config = device.get_active_configuration()
        except usb.core.USBError as exc:
            raise self._fail(f"cannot open the device: {usb_reason(exc)}") from None
        interfaces = [intf for intf in config if intf.bAlternateSetting == 0]
        numbers = ", ".join(str(intf.bInterfaceNumber) for intf in interfaces)
        if url.interface is not None:
            chosen = [intf for intf in interfaces if intf.bInterfaceNumber == url.interface]
            if not chosen:
                raise self._fail(f"no interface {url.interface} (interfaces: {numbers})")
        elif url.endpoint is not None:
            chosen = [intf for intf in interfaces
                      if usb.util.find_descriptor(intf, bEndpointAddress=url.endpoint) is not None]
            if not chosen:
                raise self._fail(f"no endpoint 0x{url.endpoint:02x} on any interface")
        else:
            chosen = interfaces
        if not chosen:
            raise self._fail("the device has no interface")
        intf = chosen[0]
        number = intf.bInterfaceNumber

        if url.endpoint is not None:
            self._in_ep = self._named_ep(usb, intf, url.endpoint)
        else:
            self._in_ep = _first_ep(usb, intf, usb.util.ENDPOINT_IN)
            if self._in_ep is None:
                others = [str(i.bInterfaceNumber) for i in interfaces
                          if _first_ep(usb, i, usb.util.ENDPOINT_IN) is not None]
                hint = f" (interface {', '.join(others)} has one: add interface=N)" if others else ""
                raise self._fail(f"interface {number} has no bulk or interrupt IN endpoint{hint}")
        out = url.out
        self._out_ep = _first_ep(usb, intf, usb.util.ENDPOINT_OUT) if out is None else self._named_ep(usb, intf, out)

        try:
            active = device.is_kernel_driver_active(number)
        except NotImplementedError:  # no kernel drivers to detach on this platform
            active = False
        except usb.core.USBError as exc:
            raise self._fail(f"cannot open the device: {usb_reason(exc)}") from None
        if active:
            try:
                device.detach_kernel_driver(number)
            except (usb.core.USBError, NotImplementedError) as exc:
                raise self._fail(f"cannot detach the kernel driver of interface {number}: {usb_reason(exc)}") from None
            self._reattach = True
        self._interface = number  # from here on, close() releases it
        try:
            usb.util.claim_interface(device, number)
        except usb.core.USBError as exc:
            raise self._fail(f"cannot claim interface {number}: {usb_reason(exc)}") from None

    def _named_ep(self, usb, intf, address: int):  # type: ignore[no-untyped-def]
        """The endpoint ``address`` of ``intf``, which must be bulk or interrupt."""
        endpoint = usb.util.find_descriptor(intf, bEndpointAddress=address)
        if endpoint is None:
            raise self._fail(f"interface {intf.bInterfaceNumber} has no endpoint 0x{address:02x}")
        if usb.util.endpoint_type(endpoint.bmAttributes) not in _STREAMING:
            raise self._fail(f"endpoint 0x{address:02x} is neither bulk nor interrupt")
        return endpoint

    def _release(self) -> None:
        """Give the interface back (and its kernel driver), close the device handle."""
        device, number, self._device = self._device, self._interface, None
        if device is None:
            return
        usb = self._usb
        if number is not None:
            with contextlib.suppress(usb.core.USBError):  # unplugged: nothing to release
                usb.util.release_interface(device, number)
            if self._reattach:
                with contextlib.suppress(usb.core.USBError, NotImplementedError):
                    device.attach_kernel_driver(number)
        self._interface = None
        self._reattach = False
        usb.util.dispose_resources(device)

    # -- reading ----------------------------------------------------------------
    def _transfer(self, timeout_ms: int) -> int:
        """One IN transfer of one packet, waiting at most TIMEOUT_MS (>= 1) milliseconds;
        appends to the buffer and returns the number of bytes received (0 on timeout)."""
        try:
            data = self._device.read(self._in_ep.bEndpointAddress, _packet_size(self._in_ep), timeout=timeout_ms)
        except self._usb.core.USBTimeoutError:
            return 0
        except self._usb.core.USBError as exc:
            raise self._fail(f"read failed: {usb_reason(exc)}") from None
        self._buffer += data
        return len(data)

    def _drain(self, limit: int = DRAIN_LIMIT) -> None:
        """Poll until the endpoint has nothing more (or ``limit`` bytes are buffered)."""
        while len(self._buffer) < limit and self._transfer(POLL_MS):
            pass

    @property
    def in_waiting(self) -> int:
        """Bytes buffered, after polling the endpoint for what has arrived."""
        self._require_open()
        self._drain()
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        """Up to SIZE bytes, within the port's timeout (seconds; see the module docstring)."""
        self._require_open()
        timeout = Timeout(self._timeout)
        while len(self._buffer) < size:
            if timeout.is_non_blocking:
                self._drain(size)
                break
            if timeout.is_infinite:
                wait_ms = self._url.timeout_ms
            else:
                left = timeout.time_left()
                if left <= 0:
                    break
                wait_ms = max(1, min(self._url.timeout_ms, math.ceil(left * 1000)))
            self._transfer(wait_ms)
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def reset_input_buffer(self) -> None:
        """Drop buffered bytes and whatever the endpoint holds now."""
        self._require_open()
        self._drain()
        self._buffer.clear()

    # -- writing ----------------------------------------------------------------
    def write(self, data) -> int:  # type: ignore[no-untyped-def]
        """Send DATA to the OUT endpoint in one transfer; return the bytes written.

        Time limit: ``write_timeout`` (seconds) when set, else ``timeout_ms``; on expiry
        ``SerialTimeoutException``.
        """
        self._require_open()
        data = to_bytes(data)
        if self._out_ep is None:
            raise self._fail(f"interface {self._interface} has no OUT endpoint: the device cannot be written to")
        if not data:
            return 0
        timeout_s = self._write_timeout
        limit_ms = self._url.timeout_ms if timeout_s is None else max(1, math.ceil(timeout_s * 1000))
        try:
            return int(self._device.write(self._out_ep.bEndpointAddress, data, timeout=limit_ms))
        except self._usb.core.USBTimeoutError:
            raise SerialTimeoutException(f"{self._port}: write timed out after {limit_ms} ms") from None
        except self._usb.core.USBError as exc:
            raise self._fail(f"write failed: {usb_reason(exc)}") from None

    # -- closing and the rest ----------------------------------------------------
    def close(self) -> None:
        self.is_open = False
        self._release()
        self._buffer = bytearray()


def _first_ep(usb, interface, direction: int):  # type: ignore[no-untyped-def]
    """The first bulk or interrupt endpoint of ``interface`` in ``direction``, or None."""
    return usb.util.find_descriptor(interface, custom_match=lambda e: (
        usb.util.endpoint_direction(e.bEndpointAddress) == direction
        and usb.util.endpoint_type(e.bmAttributes) in _STREAMING))  # fmt: skip
