"""A fake pyusb backend: USB devices that stream bytes, with no hardware and no libusb.

``FakeBackend`` implements ``usb.backend.IBackend`` the way pyusb's libusb1 backend does
(logical indices, descriptor objects with the descriptor fields, buffers filled in
place, ``USBError`` / ``USBTimeoutError`` with libusb's texts and errno values), so
``usb.core.find``, ``usb.core.Device``, ``usb.util.get_string`` and pyusb's endpoint
lookup run for real on top of it.

A ``FakeDevice`` streams what a test ``feed``s on an IN endpoint, cut into packets of
the endpoint's wMaxPacketSize, and records what is written to its OUT endpoints.
libusb semantics the handler must respect are enforced: a transfer on an unclaimed
interface fails, a timeout of 0 (libusb: "no time limit") is refused instead of
hanging, a packet larger than the read buffer is an overflow, a kernel driver must be
detached before claiming, an unplugged device fails with ENODEV.
"""

from __future__ import annotations

import array
import collections
import errno
import threading
import time
from dataclasses import dataclass

import usb.backend
import usb.core

BULK, INTR, ISO = 2, 3, 1  # bmAttributes transfer types

# libusb error codes and pyusb's texts for them (usb/backend/libusb1.py)
ERRORS = {
    errno.EACCES: (-3, "Access denied (insufficient permissions)"),
    errno.ENODEV: (-4, "No such device (it may have been disconnected)"),
    errno.ENOENT: (-5, "Entity not found"),
    errno.EBUSY: (-6, "Resource busy"),
    errno.EOVERFLOW: (-8, "Overflow"),
    errno.EPIPE: (-9, "Pipe error"),
}


def usb_error(code: int) -> usb.core.USBError:
    backend_code, text = ERRORS[code]
    return usb.core.USBError(text, backend_code, code)


@dataclass
class Endpoint:
    address: int  # bEndpointAddress: bit 7 set for IN
    kind: int = BULK  # bmAttributes & 3
    max_packet: int = 64  # wMaxPacketSize (bytes)


@dataclass
class Interface:
    number: int
    endpoints: list[Endpoint]
    klass: int = 0xFF  # vendor specific


class Descriptor:
    """A descriptor: its fields as attributes (what pyusb's ``_set_attr`` copies)."""

    def __init__(self, **fields: object) -> None:
        self.__dict__.update(fields)
        self.extra_descriptors = []


class FakeDevice:
    """One USB device: descriptors, strings, IN packet queues, OUT records."""

    def __init__(
        self,
        vid: int,
        pid: int,
        serial: str | None = None,
        product: str | None = None,
        manufacturer: str | None = None,
        interfaces: list[Interface] | None = None,
        bus: int = 1,
        address: int = 2,
        device_class: int = 0,
        kernel_driver: bool = False,
        access_denied: bool = False,
        configured: bool = True,
    ) -> None:
        self.vid, self.pid = vid, pid
        self.bus, self.address = bus, address
        self.device_class = device_class
        self.interfaces = interfaces if interfaces is not None else [
            Interface(0, [Endpoint(0x81, BULK, 64), Endpoint(0x02, BULK, 64)])
        ]
        # string descriptors: index 1 manufacturer, 2 product, 3 serial number
        self.strings = {1: manufacturer, 2: product, 3: serial}
        self.access_denied = access_denied
        self.configuration = 1 if configured else 0
        self.kernel_driver = {intf.number: kernel_driver for intf in self.interfaces}
        self.claimed: set[int] = set()
        self.open_handles = 0
        self.unplugged = False
        self.written: dict[int, bytearray] = collections.defaultdict(bytearray)
        self.reads: list[tuple[int, int, int]] = []  # (endpoint, buffer length, timeout ms)
        self.events: list[str] = []
        self._queues: dict[int, collections.deque[bytes]] = collections.defaultdict(collections.deque)
        self._cond = threading.Condition()

    # -- test side ----------------------------------------------------------------
    def endpoint(self, address: int) -> Endpoint:
        for intf in self.interfaces:
            for ep in intf.endpoints:
                if ep.address == address:
                    return ep
        raise KeyError(hex(address))

    def feed(self, data: bytes, ep: int = 0x81) -> None:
        """Stream DATA on IN endpoint EP, cut into packets of its wMaxPacketSize."""
        size = self.endpoint(ep).max_packet
        self.feed_packets([data[i : i + size] for i in range(0, len(data), size)], ep)

    def feed_packets(self, packets: list[bytes], ep: int = 0x81) -> None:
        """Queue these packets, as they are, on IN endpoint EP."""
        limit = self.endpoint(ep).max_packet
        assert all(len(p) <= limit for p in packets), "packet larger than wMaxPacketSize"
        with self._cond:
            self._queues[ep].extend(bytes(p) for p in packets)
            self._cond.notify_all()

    def pending(self, ep: int = 0x81) -> int:
        """Packets not read yet."""
        with self._cond:
            return len(self._queues[ep])

    def unplug(self) -> None:
        with self._cond:
            self.unplugged = True
            self._cond.notify_all()

    # -- backend side -------------------------------------------------------------
    def read(self, ep: int, buff: array.array, timeout_ms: int) -> int:
        if timeout_ms <= 0:  # libusb would wait forever: refuse instead of hanging the test
            raise AssertionError(f"read of endpoint 0x{ep:02x} with timeout {timeout_ms} (no time limit)")
        self.reads.append((ep, len(buff), timeout_ms))
        deadline = time.monotonic() + timeout_ms / 1000
        queue = self._queues[ep]
        with self._cond:
            while not queue:
                if self.unplugged:
                    raise usb_error(errno.ENODEV)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
                self._cond.wait(left)
            size = self.endpoint(ep).max_packet
            n = 0
            while queue:
                packet = queue[0]
                if n + len(packet) > len(buff):
                    if n == 0:
                        raise usb_error(errno.EOVERFLOW)
                    break
                queue.popleft()
                buff[n : n + len(packet)] = array.array("B", packet)
                n += len(packet)
                if len(packet) < size:  # a short packet ends the transfer
                    break
            return n


class _Handle:
    def __init__(self, device: FakeDevice) -> None:
        self.device = device


class FakeBackend(usb.backend.IBackend):
    """pyusb backend over FakeDevices (pass to ``usb.core.find(backend=...)``)."""

    def __init__(self, *devices: FakeDevice) -> None:
        super().__init__()
        self.devices = list(devices)

    # -- enumeration and descriptors ------------------------------------------------
    def enumerate_devices(self):  # type: ignore[no-untyped-def]
        return iter(list(self.devices))

    def get_parent(self, dev: FakeDevice) -> None:
        return None

    def get_device_descriptor(self, dev: FakeDevice) -> Descriptor:
        index = {i: (i if s is not None else 0) for i, s in dev.strings.items()}
        return Descriptor(
            bLength=18,
            bDescriptorType=0x01,
            bcdUSB=0x0200,
            bDeviceClass=dev.device_class,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=dev.vid,
            idProduct=dev.pid,
            bcdDevice=0x0100,
            iManufacturer=index[1],
            iProduct=index[2],
            iSerialNumber=index[3],
            bNumConfigurations=1,
            address=dev.address,
            bus=dev.bus,
            port_number=1,
            port_numbers=(1,),
            speed=3,  # high speed
        )

    def get_configuration_descriptor(self, dev: FakeDevice, config: int) -> Descriptor:
        if config != 0:
            raise IndexError("configuration index out of range")
        return Descriptor(
            bLength=9,
            bDescriptorType=0x02,
            wTotalLength=9 + sum(9 + 7 * len(i.endpoints) for i in dev.interfaces),
            bNumInterfaces=len(dev.interfaces),
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=50,
        )

    def get_interface_descriptor(self, dev: FakeDevice, intf: int, alt: int, config: int) -> Descriptor:
        if config != 0 or intf >= len(dev.interfaces) or alt != 0:
            raise IndexError("interface index out of range")
        i = dev.interfaces[intf]
        return Descriptor(
            bLength=9,
            bDescriptorType=0x04,
            bInterfaceNumber=i.number,
            bAlternateSetting=0,
            bNumEndpoints=len(i.endpoints),
            bInterfaceClass=i.klass,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
        )

    def get_endpoint_descriptor(self, dev: FakeDevice, ep: int, intf: int, alt: int, config: int) -> Descriptor:
        if config != 0 or intf >= len(dev.interfaces) or alt != 0 or ep >= len(dev.interfaces[intf].endpoints):
            raise IndexError("endpoint index out of range")
        e = dev.interfaces[intf].endpoints[ep]
        return Descriptor(
            bLength=7,
            bDescriptorType=0x05,
            bEndpointAddress=e.address,
            bmAttributes=e.kind,
            wMaxPacketSize=e.max_packet,
            bInterval=1,
            bRefresh=0,
            bSynchAddress=0,
        )

    # -- handles, configuration, interfaces ----------------------------------------------
    def open_device(self, dev: FakeDevice) -> _Handle:
        if dev.unplugged:
            raise usb_error(errno.ENODEV)
        if dev.access_denied:
            raise usb_error(errno.EACCES)
        dev.open_handles += 1
        dev.events.append("open")
        return _Handle(dev)

    def close_device(self, handle: _Handle) -> None:
        handle.device.open_handles -= 1
        handle.device.events.append("close")

    def get_configuration(self, handle: _Handle) -> int:
        return handle.device.configuration

    def set_configuration(self, handle: _Handle, config_value: int) -> None:
        handle.device.configuration = config_value
        handle.device.events.append(f"set_configuration {config_value}")

    def set_interface_altsetting(self, handle: _Handle, intf: int, altsetting: int) -> None:
        pass

    def _interface(self, handle: _Handle, intf: int) -> None:
        if intf not in {i.number for i in handle.device.interfaces}:
            raise usb_error(errno.ENOENT)

    def claim_interface(self, handle: _Handle, intf: int) -> None:
        dev = handle.device
        self._interface(handle, intf)
        if dev.kernel_driver[intf] or intf in dev.claimed:
            raise usb_error(errno.EBUSY)
        dev.claimed.add(intf)
        dev.events.append(f"claim {intf}")

    def release_interface(self, handle: _Handle, intf: int) -> None:
        handle.device.claimed.discard(intf)
        handle.device.events.append(f"release {intf}")

    def is_kernel_driver_active(self, handle: _Handle, intf: int) -> bool:
        self._interface(handle, intf)
        return handle.device.kernel_driver[intf]

    def detach_kernel_driver(self, handle: _Handle, intf: int) -> None:
        handle.device.kernel_driver[intf] = False
        handle.device.events.append(f"detach {intf}")

    def attach_kernel_driver(self, handle: _Handle, intf: int) -> None:
        handle.device.kernel_driver[intf] = True
        handle.device.events.append(f"attach {intf}")

    # -- transfers ------------------------------------------------------------------
    def _endpoint(self, handle: _Handle, ep: int, intf: int, kind: int) -> FakeDevice:
        dev = handle.device
        if intf not in dev.claimed:
            raise AssertionError(f"transfer on interface {intf}, which is not claimed")
        assert dev.endpoint(ep).kind == kind, f"wrong transfer type for endpoint 0x{ep:02x}"
        return dev

    def bulk_read(self, handle: _Handle, ep: int, intf: int, buff: array.array, timeout: int) -> int:
        return self._endpoint(handle, ep, intf, BULK).read(ep, buff, timeout)

    def intr_read(self, handle: _Handle, ep: int, intf: int, buff: array.array, timeout: int) -> int:
        return self._endpoint(handle, ep, intf, INTR).read(ep, buff, timeout)

    def _write(self, handle: _Handle, ep: int, intf: int, data: array.array, timeout: int, kind: int) -> int:
        dev = self._endpoint(handle, ep, intf, kind)
        if timeout <= 0:
            raise AssertionError(f"write to endpoint 0x{ep:02x} with timeout {timeout} (no time limit)")
        if dev.unplugged:
            raise usb_error(errno.ENODEV)
        dev.written[ep] += data.tobytes()
        return len(data) * data.itemsize

    def bulk_write(self, handle: _Handle, ep: int, intf: int, data: array.array, timeout: int) -> int:
        return self._write(handle, ep, intf, data, timeout, BULK)

    def intr_write(self, handle: _Handle, ep: int, intf: int, data: array.array, timeout: int) -> int:
        return self._write(handle, ep, intf, data, timeout, INTR)

    def ctrl_transfer(self, handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):  # type: ignore[no-untyped-def]
        """GET_DESCRIPTOR(STRING) only: language table at index 0, UTF-16LE strings after."""
        dev = handle.device
        if dev.unplugged:
            raise usb_error(errno.ENODEV)
        if bmRequestType != 0x80 or bRequest != 0x06 or wValue >> 8 != 0x03:
            raise usb_error(errno.EPIPE)  # a stall: request not supported
        index = wValue & 0xFF
        if index == 0:
            payload = bytes([4, 0x03, 0x09, 0x04])  # one language: 0x0409 (English, US)
        else:
            text = dev.strings.get(index)
            if text is None or wIndex != 0x0409:
                raise usb_error(errno.EPIPE)
            encoded = text.encode("utf-16-le")
            payload = bytes([2 + len(encoded), 0x03]) + encoded
        n = min(len(payload), len(data))
        data[:n] = array.array("B", payload[:n])
        return n
