"""``arva-bench devices``: the devices this machine can read, and the URL that opens each.

Three sources, each used when its library is there: serial ports (pyserial's
``list_ports``: the device path), HID devices (hidapi, the ``hid`` extra: CP2110/CP2114
bridges get a ``cp2110://`` URL, others none) and USB devices (pyusb, the ``usb`` extra:
``usb://VID:PID?serial=S``, hubs left out). Output, the ``--json`` keys and what a missing
library does: docs/transports.md ("Finding the URL"). Exit status 0, even when nothing is
found.
"""

from __future__ import annotations

import argparse
import errno
import json
import re
import sys
import urllib.parse
from collections.abc import Iterable
from dataclasses import asdict, dataclass

from serial.tools import list_ports

from .urlhandler import protocol_usb

#: (VID, PID) of the HID UART bridges pyserial's ``cp2110://`` handler drives (AN434).
CP2110_IDS = frozenset({(0x10C4, 0xEA80), (0x10C4, 0xEAB0)})  # CP2110, CP2114
USB_CLASS_HUB = 0x09

HID_MISSING = "HID: not listed (install the extra: pip install 'arva-bench[hid]')"
USB_MISSING = "USB: not listed (install the extra: pip install 'arva-bench[usb]')"
COLUMNS = ("KIND", "URL", "VID:PID", "SERIAL", "DESCRIPTION")


@dataclass
class Found:
    """One device and the URL that opens it (``None`` when nothing does)."""

    kind: str
    url: str | None
    vid: int | None
    pid: int | None
    serial_number: str | None
    manufacturer: str | None
    description: str | None
    device: str
    note: str | None = None

    @property
    def ids(self) -> str | None:
        """``vvvv:pppp`` in lowercase hex, or None."""
        return None if self.vid is None or self.pid is None else f"{self.vid:04x}:{self.pid:04x}"

    def to_json(self) -> dict:
        out = asdict(self)
        out["vid"] = None if self.vid is None else f"{self.vid:04x}"
        out["pid"] = None if self.pid is None else f"{self.pid:04x}"
        return out


# -- the three sources -------------------------------------------------------------------
def serial_ports() -> list[Found]:
    """Serial ports pyserial sees, in natural order of their paths."""
    found = [
        Found(kind="serial", url=port.device, vid=port.vid, pid=port.pid, serial_number=port.serial_number or None,
              manufacturer=port.manufacturer or None, device=port.device,
              description=port.description if port.description not in (None, "", "n/a") else None)
        for port in list_ports.comports()
    ]
    return sorted(found, key=lambda f: _natural(f.device))


def cp2110_url(path: bytes) -> str | None:
    """The ``cp2110://`` URL pyserial's handler turns back into the hidapi PATH, or None
    when the path cannot be written as one (e.g. Windows paths, which hold ``#``)."""
    try:
        text = path.decode("utf-8")
    except UnicodeDecodeError:
        return None
    url = "cp2110://" + text
    parts = urllib.parse.urlsplit(url)
    return url if (parts.netloc or parts.path) == text and not parts.query and not parts.fragment else None


def hid_devices(err) -> list[Found]:  # type: ignore[no-untyped-def]
    """HID devices hidapi sees (one per path), CP2110/CP2114 bridges with their URL."""
    try:
        import hid
    except ImportError:
        print(HID_MISSING, file=err)
        return []
    try:
        entries = hid.enumerate()
    except Exception as exc:  # noqa: BLE001 - a broken hidapi must not hide the other sources
        print(f"HID: not listed (hidapi failed: {exc})", file=err)
        return []
    found: dict[bytes, Found] = {}
    for entry in entries:
        path = entry.get("path") or b""
        if isinstance(path, str):  # other hidapi bindings give str paths
            path = path.encode("utf-8")
        if path in found:
            continue  # hidapi lists one entry per usage of the same device
        vid, pid = entry.get("vendor_id"), entry.get("product_id")
        url = note = None
        if (vid, pid) in CP2110_IDS:
            url = cp2110_url(path)
            if url is None:
                note = "its path cannot be written as a cp2110:// URL"
        found[path] = Found(kind="hid", url=url, vid=vid, pid=pid, serial_number=entry.get("serial_number") or None,
                            manufacturer=entry.get("manufacturer_string") or None,
                            description=entry.get("product_string") or None,
                            device=path.decode("utf-8", "replace"), note=note)
    return sorted(found.values(), key=lambda f: _natural(f.device))


def usb_devices(err) -> list[Found]:  # type: ignore[no-untyped-def]
    """USB devices pyusb sees (hubs left out), with strings where readable."""
    try:
        usb = protocol_usb.import_pyusb()
    except ImportError:
        print(USB_MISSING, file=err)
        return []
    try:
        devices = list(usb.core.find(find_all=True, backend=protocol_usb.BACKEND))
    except usb.core.NoBackendError:
        print(f"USB: not listed ({protocol_usb.NO_BACKEND})", file=err)
        return []
    except usb.core.USBError as exc:
        print(f"USB: not listed (cannot list USB devices: {protocol_usb.usb_reason(exc)})", file=err)
        return []
    found: list[Found] = []
    denied = False
    for dev in sorted(devices, key=lambda d: (d.bus or 0, d.address or 0)):
        if dev.bDeviceClass == USB_CLASS_HUB:
            continue
        manufacturer = product = serial_number = note = None
        try:
            manufacturer = protocol_usb.read_string(dev, dev.iManufacturer)
            product = protocol_usb.read_string(dev, dev.iProduct)
            serial_number = protocol_usb.read_string(dev, dev.iSerialNumber)
        except (usb.core.USBError, ValueError, NotImplementedError) as exc:
            note = f"strings unreadable: {getattr(exc, 'strerror', None) or str(exc)}"
            denied = denied or getattr(exc, "errno", None) == errno.EACCES
        finally:
            usb.util.dispose_resources(dev)
        url = f"usb://{dev.idVendor:04x}:{dev.idProduct:04x}"
        if serial_number:
            url += "?serial=" + urllib.parse.quote(serial_number, safe="")
        found.append(Found(kind="usb", url=url, vid=dev.idVendor, pid=dev.idProduct,
                           serial_number=serial_number or None, manufacturer=manufacturer or None,
                           description=product or None, device=f"bus {dev.bus} address {dev.address}", note=note))
    if denied:
        print(f"USB: some devices could not be opened: {protocol_usb.UDEV_HINT}", file=err)
    return found


def mark_duplicates(usb: Iterable[Found], others: list[Found]) -> None:
    """Note on each USB device the serial port or HID bridge it also is."""
    for dev in usb:
        also = [o.url or f"HID {o.device}" for o in others
                if o.vid is not None and (o.vid, o.pid, o.serial_number) == (dev.vid, dev.pid, dev.serial_number)]
        if also:
            dev.note = "; ".join(filter(None, [dev.note, "also " + ", ".join(also)]))


# -- output ------------------------------------------------------------------------------
def table(found: list[Found]) -> list[str]:
    """Lines of the aligned table (header first), with no trailing blanks."""
    rows = [COLUMNS]
    for f in found:
        description = " ".join(filter(None, [f.manufacturer, f.description])) or None
        if f.note:
            description = f"{description or '-'} ({f.note})"
        rows.append(tuple(_printable(v) if v else "-" for v in (f.kind, f.url, f.ids, f.serial_number, description)))
    widths = [max(len(row[i]) for row in rows) for i in range(len(COLUMNS) - 1)]
    return ["  ".join([*(c.ljust(w) for c, w in zip(row, widths)), row[-1]]).rstrip() for row in rows]


def _printable(text: str) -> str:
    return "".join(ch if ch.isprintable() else "?" for ch in text)


def _natural(text: str) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def run(args: argparse.Namespace) -> int:
    ports = serial_ports()
    hids = hid_devices(sys.stderr)
    usbs = usb_devices(sys.stderr)
    mark_duplicates(usbs, ports + hids)
    found = ports + hids + usbs
    if args.json:
        print(json.dumps([f.to_json() for f in found], indent=None))
    elif found:
        print("\n".join(table(found)))
    else:
        print("no devices found", file=sys.stderr)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "devices",
        help="list serial ports, HID UART bridges and USB devices with the URL that opens each",
        description=(
            "List the serial ports, HID devices (with the hid extra) and USB devices (with the usb "
            "extra and libusb) of this machine, one per line, with the pyserial URL that opens each: "
            "a device path, cp2110://PATH for CP2110/CP2114 HID UART bridges, usb://VID:PID?serial=S "
            "for raw USB endpoints. A missing library is reported on stderr and the others are "
            "listed. Exit status 0, even when nothing is found."
        ),
    )
    p.add_argument("--json", action="store_true", help="print one JSON array instead of the table")
