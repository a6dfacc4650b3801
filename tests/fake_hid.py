"""A fake ``hid`` module (cython-hidapi's API) with Silicon Labs CP2110 HID UART bridges.

Inject it with ``monkeypatch.setitem(sys.modules, "hid", FakeHid(...))``: pyserial's
``cp2110://`` handler and ``arva-bench devices`` then run their real code over it.

API as in cython-hidapi (``hidapi`` on PyPI), which pyserial's handler is written for:
``hid.enumerate(vendor_id=0, product_id=0)`` returns dicts with ``path`` (bytes),
``vendor_id``, ``product_id``, ``serial_number``, ``release_number``,
``manufacturer_string``, ``product_string``, ``usage_page``, ``usage``,
``interface_number``; ``hid.device()`` has ``open_path``, ``set_nonblocking``,
``send_feature_report``, ``get_feature_report``, ``read(max_length, timeout_ms=0)``
(a list of ints, empty on timeout), ``write`` and ``close``; failures raise ``OSError``.

The CP2110 side follows Silicon Labs AN434: the UART is configured by feature report
0x50 (baud rate big-endian u32, parity, flow control, data bits, stop bits) and enabled
by report 0x41; received UART bytes come as interrupt reports whose report ID is the
payload length (1..63); the host sends data the same way. Bytes the "UART" receives
while it is disabled are lost, as on the chip.
"""

from __future__ import annotations

import collections
import struct
import threading
import time
import types

CP2110 = (0x10C4, 0xEA80)
REPORT_UART_ENABLE = 0x41
REPORT_PURGE_FIFOS = 0x43
REPORT_UART_CONFIG = 0x50
REPORT_LINE_BREAK_START = 0x51
REPORT_LINE_BREAK_STOP = 0x52
MAX_PAYLOAD = 63  # data bytes in one interrupt report


class HidDevice:
    """One HID device as ``hid.enumerate`` sees it; a CP2110 when vid:pid say so."""

    def __init__(
        self,
        path: bytes,
        vid: int = CP2110[0],
        pid: int = CP2110[1],
        serial: str = "",
        product: str = "CP2110 HID USB-to-UART Bridge",
        manufacturer: str = "Silicon Laboratories",
        interface: int = 0,
        usage_page: int = 0xFF00,
        usage: int = 1,
    ) -> None:
        self.path, self.vid, self.pid = path, vid, pid
        self.serial, self.product, self.manufacturer = serial, product, manufacturer
        self.interface, self.usage_page, self.usage = interface, usage_page, usage
        self.uart_enabled = False
        self.uart_config: tuple[int, int, int, int, int] | None = None  # baud, parity, flow, bits, stop
        self.feature_reports: list[bytes] = []  # every feature report the host sent
        self.tx = bytearray()  # bytes the host wrote to the UART
        self.reads: list[tuple[int, int]] = []  # (max_length, timeout_ms) of every read
        self.is_open = False
        self._reports: collections.deque[list[int]] = collections.deque()
        self._cond = threading.Condition()

    def info(self) -> dict:
        return {
            "path": self.path,
            "vendor_id": self.vid,
            "product_id": self.pid,
            "serial_number": self.serial,
            "release_number": 0x0100,
            "manufacturer_string": self.manufacturer,
            "product_string": self.product,
            "usage_page": self.usage_page,
            "usage": self.usage,
            "interface_number": self.interface,
        }

    # -- the UART side --------------------------------------------------------------
    def receive(self, data: bytes, chunk: int = MAX_PAYLOAD) -> None:
        """The UART receives DATA: queue it as reports of at most CHUNK (<= 63) bytes."""
        assert 1 <= chunk <= MAX_PAYLOAD
        with self._cond:
            if not self.uart_enabled:
                return  # lost, as on the chip
            for i in range(0, len(data), chunk):
                part = data[i : i + chunk]
                self._reports.append([len(part), *part])
            self._cond.notify_all()

    # -- the host side (called through FakeHidHandle) ----------------------------------
    def feature(self, report: bytes) -> None:
        self.feature_reports.append(report)
        report_id = report[0]
        if report_id == REPORT_UART_CONFIG:
            assert len(report) == 9, f"UART config report must be 9 bytes, got {report.hex()}"
            self.uart_config = struct.unpack(">LBBBB", report[1:])
        elif report_id == REPORT_UART_ENABLE:
            self.uart_enabled = bool(report[1])
        elif report_id == REPORT_PURGE_FIFOS:
            with self._cond:
                if report[1] & 0x02:
                    self._reports.clear()

    def get_feature(self, report_id: int) -> list[int]:
        if report_id == REPORT_UART_ENABLE:
            return [REPORT_UART_ENABLE, int(self.uart_enabled)]
        if report_id == REPORT_UART_CONFIG and self.uart_config is not None:
            return list(struct.pack(">BLBBBB", REPORT_UART_CONFIG, *self.uart_config))
        raise OSError("read error")

    def next_report(self, max_length: int, timeout_ms: int) -> list[int]:
        self.reads.append((max_length, timeout_ms))
        deadline = time.monotonic() + timeout_ms / 1000
        with self._cond:
            while not self._reports:
                left = deadline - time.monotonic()
                if timeout_ms == 0 or left <= 0:
                    return []
                self._cond.wait(left)
            return self._reports.popleft()[:max_length]


class FakeHidHandle:
    """``hid.device()``: a handle that opens one HidDevice by path."""

    def __init__(self, module: FakeHid) -> None:
        self._module = module
        self._device: HidDevice | None = None
        self._nonblocking = False

    def _dev(self) -> HidDevice:
        if self._device is None:
            raise ValueError("not open")
        return self._device

    def open_path(self, path: bytes) -> None:
        if not isinstance(path, bytes):
            raise TypeError("path must be bytes")
        for device in self._module.devices:
            if device.path == path:
                device.is_open = True
                self._device = device
                return
        raise OSError("open failed")

    def set_nonblocking(self, value: int) -> int:
        self._nonblocking = bool(value)
        return 0

    def send_feature_report(self, buff) -> int:  # type: ignore[no-untyped-def]
        self._dev().feature(bytes(buff))
        return len(buff)

    def get_feature_report(self, report_num: int, max_length: int) -> list[int]:
        return self._dev().get_feature(report_num)[:max_length]

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        timeout = 0 if self._nonblocking else timeout_ms
        return self._dev().next_report(max_length, timeout)

    def write(self, buff) -> int:  # type: ignore[no-untyped-def]
        data = bytes(buff)
        length = data[0]
        assert 1 <= length <= MAX_PAYLOAD and len(data) == length + 1, f"bad data report {data.hex()}"
        self._dev().tx += data[1:]
        return len(data)

    def close(self) -> None:
        if self._device is not None:
            self._device.is_open = False
        self._device = None


class FakeHid(types.ModuleType):
    """The fake ``hid`` module: ``enumerate()`` and ``device()`` over a list of HidDevices."""

    def __init__(self, *devices: HidDevice) -> None:
        super().__init__("hid")
        self.devices = list(devices)

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict]:
        return [
            d.info()
            for d in self.devices
            if vendor_id in (0, d.vid) and product_id in (0, d.pid)
        ]

    def device(self) -> FakeHidHandle:
        return FakeHidHandle(self)
