"""The usb:// pyserial URL handler, over a fake pyusb backend (pyusb's own code runs)."""

import contextlib
import threading
import time
from collections.abc import Iterator

import pytest
import serial
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb

import bench.urlhandler  # noqa: F401  (registers usb://)
from bench.urlhandler import protocol_usb
from fake_usb import BULK, INTR, ISO, Endpoint, FakeBackend, FakeDevice, Interface

EPOCH = (
    b"$PARVA,0,4,1,4,761,-62*4C\r\n"
    b"$PARVA,0,4,2,2,926,0*5D\r\n"
    b"$PARVA,0,4,3,1,1905,21*5C\r\n"
    b"$PARVA,0,4,4,3,2808,-72*7D\r\n"
)
pytestmark = pytest.mark.timeout(10)  # a handler that blocks for ever fails instead of hanging

UDEV = "on Linux, a udev rule grants access: see docs/transports.md"


@pytest.fixture
def devices(monkeypatch):
    """Install a fake backend; returns a function that plugs FakeDevices into it."""
    backend = FakeBackend()
    monkeypatch.setattr(protocol_usb, "BACKEND", backend)

    def plug(*devs):
        backend.devices.extend(devs)
        return devs[0] if len(devs) == 1 else devs

    return plug


def receiver(**kw):
    kw.setdefault("serial", "ABC")
    return FakeDevice(0x1234, 0x5678, **kw)


def read_all(port, limit=10_000):
    """Read until a read times out empty (at most 100 reads)."""
    chunks = []
    for _ in range(100):
        chunk = port.read(limit)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
    raise AssertionError("the port never ran dry")


# -- reading --------------------------------------------------------------------------
@pytest.mark.parametrize(
    "endpoints",
    [
        [Endpoint(0x81, BULK, 64), Endpoint(0x02, BULK, 64)],
        [Endpoint(0x83, INTR, 16)],
        [Endpoint(0x02, BULK, 64), Endpoint(0x84, INTR, 8), Endpoint(0x85, BULK, 64)],
    ],
    ids=["bulk", "interrupt", "first-in-endpoint"],
)
def test_reads_the_exact_stream_split_across_packets(devices, endpoints):
    dev = devices(receiver(interfaces=[Interface(0, endpoints)]))
    in_ep = next(e for e in endpoints if e.address & 0x80)
    stream = EPOCH * 3
    dev.feed(stream, in_ep.address)
    assert dev.pending(in_ep.address) == -(-len(stream) // in_ep.max_packet) > 3  # sentences straddle packets
    with serial.serial_for_url("usb://1234:5678?serial=ABC", timeout=0.2) as port:
        lines = [port.readline() for _ in range(12)]
        assert b"".join(lines) == stream
        assert lines[:4] == EPOCH.splitlines(keepends=True)
        assert port.read(100) == b""
    # every transfer asked for one packet of that endpoint, with a time limit
    assert {(ep, size) for ep, size, _ in dev.reads} == {(in_ep.address, in_ep.max_packet)}
    assert all(1 <= ms <= 1000 for _, _, ms in dev.reads)


def test_read_size_keeps_the_rest_of_a_packet(devices):
    dev = devices(receiver())
    dev.feed_packets([EPOCH[:50], EPOCH[50:64]])
    with serial.serial_for_url("usb://1234:5678", timeout=0.5) as port:
        assert port.read(10) == EPOCH[:10]
        assert port.in_waiting == 54  # the rest of the first packet and the whole second one
        assert dev.pending() == 0
        assert port.read(54) == EPOCH[10:64]
        dev.feed(EPOCH[64:])
        assert read_all(port) == EPOCH[64:]


@contextlib.contextmanager
def polled(devices, timeout: float) -> Iterator[tuple[object, serial.SerialBase]]:
    """(fake receiver, its usb:// port opened with ``timeout``); on the way out, checks
    that every transfer was a short poll (POLL_MS), never a blocking one."""
    dev = devices(receiver())
    with serial.serial_for_url("usb://1234:5678", timeout=timeout) as port:
        yield dev, port
    assert {ms for _, _, ms in dev.reads} == {protocol_usb.POLL_MS}


def test_in_waiting_polls_without_blocking(devices):
    with polled(devices, timeout=1) as (dev, port):
        t0 = time.monotonic()
        assert port.in_waiting == 0
        assert time.monotonic() - t0 < 0.25  # a blocking transfer would take timeout_ms = 1 s
        dev.feed(EPOCH)
        assert port.in_waiting == len(EPOCH)
        assert port.read(len(EPOCH)) == EPOCH


def test_non_blocking_read_returns_at_once(devices):
    with polled(devices, timeout=0) as (dev, port):
        t0 = time.monotonic()
        assert port.read(100) == b""
        assert time.monotonic() - t0 < 0.25  # a blocking transfer would take timeout_ms = 1 s
        dev.feed(EPOCH)
        assert port.read(1000) == EPOCH  # everything already there, still at once
        assert time.monotonic() - t0 < 0.5


def test_read_timeout_is_respected(devices):
    dev = devices(receiver())
    with serial.serial_for_url("usb://1234:5678", timeout=0.2) as port:
        t0 = time.monotonic()
        assert port.read(10) == b""
        elapsed = time.monotonic() - t0
    assert 0.19 <= elapsed < 0.9
    assert max(ms for _, _, ms in dev.reads) <= 200  # no transfer outlives the port timeout


def test_blocking_read_waits_for_late_data(devices):
    dev = devices(receiver())
    timer = threading.Timer(0.15, dev.feed, (EPOCH,))
    with serial.serial_for_url("usb://1234:5678?timeout_ms=50", timeout=None) as port:
        timer.start()
        try:
            t0 = time.monotonic()
            assert port.read(len(EPOCH)) == EPOCH
            assert 0.1 <= time.monotonic() - t0 < 2
        finally:
            timer.cancel()
    assert {ms for _, _, ms in dev.reads} == {50}  # blocking = a series of timeout_ms transfers


def test_reset_input_buffer_drops_pending_bytes(devices):
    dev = devices(receiver())
    dev.feed(EPOCH)
    with serial.serial_for_url("usb://1234:5678", timeout=0.1) as port:
        port.reset_input_buffer()
        dev.feed(b"$PARVA,1,4,1,4,761,-62*4D\r\n")
        assert port.readline() == b"$PARVA,1,4,1,4,761,-62*4D\r\n"


def test_unplugged_device_fails_the_read(devices):
    dev = devices(receiver())
    with serial.serial_for_url("usb://1234:5678", timeout=1) as port:
        dev.feed(EPOCH[:20])
        assert port.read(20) == EPOCH[:20]
        dev.unplug()
        with pytest.raises(serial.SerialException) as err:
            port.read(10)
    assert str(err.value) == "usb://1234:5678: read failed: No such device (it may have been disconnected)"


# -- writing --------------------------------------------------------------------------
@pytest.mark.parametrize("kind", [BULK, INTR])
def test_writes_reach_the_out_endpoint(devices, kind):
    dev = devices(receiver(interfaces=[Interface(0, [Endpoint(0x81, kind, 16), Endpoint(0x01, kind, 16)])]))
    with serial.serial_for_url("usb://1234:5678?serial=ABC", timeout=0.1) as port:
        assert port.write(b"$PCMD,RESET*00\r\n") == 16
        assert port.write(b"") == 0
        port.write(b"x" * 100)
    assert dict(dev.written) == {0x01: b"$PCMD,RESET*00\r\n" + b"x" * 100}


def test_out_option_picks_the_out_endpoint(devices):
    eps = [Endpoint(0x81, BULK), Endpoint(0x02, BULK), Endpoint(0x03, BULK)]
    dev = devices(receiver(interfaces=[Interface(0, eps)]))
    with serial.serial_for_url("usb://1234:5678?out=0x03") as port:
        port.write(b"abc")
    assert dict(dev.written) == {0x03: b"abc"}


def test_write_without_out_endpoint(devices):
    devices(receiver(interfaces=[Interface(0, [Endpoint(0x81, INTR, 8)])]))
    with serial.serial_for_url("usb://1234:5678") as port:
        with pytest.raises(serial.SerialException) as err:
            port.write(b"abc")
    assert str(err.value) == "usb://1234:5678: interface 0 has no OUT endpoint: the device cannot be written to"


# -- choosing the device, the interface, the endpoint ------------------------------------
def test_serial_number_selects_among_identical_devices(devices):
    first, second = devices(receiver(serial="XYZ", address=3), receiver(serial="ABC", address=4))
    first.feed(b"from XYZ\n")
    second.feed(b"from ABC\n")
    with serial.serial_for_url("usb://1234:5678?serial=ABC", timeout=0.5) as port:
        assert port.readline() == b"from ABC\n"
    with serial.serial_for_url("usb://1234:5678?serial=XYZ", timeout=0.5) as port:
        assert port.readline() == b"from XYZ\n"
    second.feed(b"again ABC\n")
    with serial.serial_for_url("usb://1234:5678", timeout=0.5) as port:  # no serial: the first one
        assert port.readline() == b""
    assert first.open_handles == second.open_handles == 0  # handles opened to read strings were closed


def test_vid_pid_are_hex_and_case_insensitive(devices):
    dev = devices(FakeDevice(0x10C4, 0xEA60, serial="0001"))
    dev.feed(b"ok\n")
    with serial.serial_for_url("usb://10C4:ea60?serial=0001", timeout=0.5) as port:
        assert port.readline() == b"ok\n"


def test_serial_number_with_url_escapes(devices):
    dev = devices(receiver(serial="A&B 1"))
    dev.feed(b"ok\n")
    with serial.serial_for_url("usb://1234:5678?serial=A%26B%201", timeout=0.5) as port:
        assert port.readline() == b"ok\n"


def test_interface_and_endpoint_options(devices):
    interfaces = [
        Interface(0, [Endpoint(0x81, INTR, 8)]),  # a notification endpoint, say
        Interface(1, [Endpoint(0x82, BULK, 64), Endpoint(0x83, BULK, 64), Endpoint(0x04, BULK, 64)]),
    ]
    dev = devices(receiver(interfaces=interfaces))
    dev.feed(b"notify\n", 0x81)
    dev.feed(b"data 82\n", 0x82)
    dev.feed(b"data 83\n", 0x83)
    with serial.serial_for_url("usb://1234:5678?interface=1", timeout=0.5) as port:
        assert port.readline() == b"data 82\n"
        port.write(b"w")
    with serial.serial_for_url("usb://1234:5678?endpoint=0x83", timeout=0.5) as port:  # interface found
        assert port.readline() == b"data 83\n"
    with serial.serial_for_url("usb://1234:5678?endpoint=129", timeout=0.5) as port:
        assert port.readline() == b"notify\n"
    assert dict(dev.written) == {0x04: b"w"}


def test_kernel_driver_is_detached_and_given_back(devices):
    dev = devices(receiver(kernel_driver=True))
    dev.feed(b"ok\n")
    with serial.serial_for_url("usb://1234:5678", timeout=0.5) as port:
        assert port.readline() == b"ok\n"
    assert dev.events == ["open", "detach 0", "claim 0", "release 0", "attach 0", "close"]
    assert dev.kernel_driver == {0: True} and dev.open_handles == 0


def test_unconfigured_device_gets_its_first_configuration(devices):
    dev = devices(receiver(configured=False))
    dev.feed(b"ok\n")
    with serial.serial_for_url("usb://1234:5678", timeout=0.5) as port:
        assert port.readline() == b"ok\n"
    assert "set_configuration 1" in dev.events


def test_close_and_reopen(devices):
    dev = devices(receiver())
    port = serial.serial_for_url("usb://1234:5678", timeout=0.5)
    port.close()
    assert dev.claimed == set() and dev.open_handles == 0
    with pytest.raises(serial.PortNotOpenError):
        port.read(1)
    dev.feed(b"ok\n")
    port.open()
    assert port.readline() == b"ok\n"
    port.close()


# -- errors: one line naming the URL and the reason ------------------------------------------
@pytest.mark.parametrize(
    "url, message",
    [
        ("usb://1234:9999", "usb://1234:9999: no USB device 1234:9999 found"),
        (
            "usb://1234:5678?serial=NOPE",
            "usb://1234:5678?serial=NOPE: no USB device 1234:5678 with serial number 'NOPE'"
            " (connected: 'ABC', 'XYZ', no serial number)",
        ),
        (
            "usb://1234:5678?interface=3",
            "usb://1234:5678?interface=3: no interface 3 (interfaces: 0, 1)",
        ),
        ("usb://1234:5678?endpoint=0x8f", "usb://1234:5678?endpoint=0x8f: no endpoint 0x8f on any interface"),
        (
            "usb://1234:5678?interface=0&endpoint=0x82",
            "usb://1234:5678?interface=0&endpoint=0x82: interface 0 has no endpoint 0x82",
        ),
        ("usb://1234:5678?out=0x05", "usb://1234:5678?out=0x05: interface 0 has no endpoint 0x05"),
    ],
)
def test_device_errors(devices, url, message):
    two = [Interface(0, [Endpoint(0x81, BULK)]), Interface(1, [Endpoint(0x82, BULK)])]
    devices(receiver(serial="ABC", interfaces=two), receiver(serial="XYZ"), receiver(serial=None))
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url(url)
    assert str(err.value) == message


def test_no_in_endpoint(devices):
    devices(receiver(interfaces=[Interface(0, [Endpoint(0x01, BULK)]), Interface(2, [Endpoint(0x83, INTR)])]))
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678")
    assert str(err.value) == (
        "usb://1234:5678: interface 0 has no bulk or interrupt IN endpoint (interface 2 has one: add interface=N)"
    )
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678?interface=0")
    assert str(err.value) == "usb://1234:5678?interface=0: interface 0 has no bulk or interrupt IN endpoint (interface 2 has one: add interface=N)"


def test_isochronous_endpoint_is_refused(devices):
    devices(receiver(interfaces=[Interface(0, [Endpoint(0x81, ISO, 192)])]))
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678?endpoint=0x81")
    assert str(err.value) == "usb://1234:5678?endpoint=0x81: endpoint 0x81 is neither bulk nor interrupt"


def test_access_denied(devices):
    dev = devices(receiver(access_denied=True))
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678")
    assert str(err.value) == f"usb://1234:5678: cannot open the device: Access denied (insufficient permissions); {UDEV}"
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678?serial=ABC")
    assert str(err.value) == (
        "usb://1234:5678?serial=ABC: no USB device 1234:5678 with serial number 'ABC'"
        f" (1 whose serial number cannot be read: Access denied (insufficient permissions); {UDEV})"
    )
    assert dev.open_handles == 0


def test_interface_held_by_someone_else(devices):
    dev = devices(receiver())
    with serial.serial_for_url("usb://1234:5678"):
        dev.claimed.add(0)  # as if another process had it
        with pytest.raises(serial.SerialException) as err:
            serial.serial_for_url("usb://1234:5678")
    assert str(err.value) == "usb://1234:5678: cannot claim interface 0: Resource busy"


@pytest.mark.parametrize(
    "url, reason",
    [
        ("usb://12345:1", "expected " + protocol_usb.USAGE),
        ("usb://1234", "expected " + protocol_usb.USAGE),
        ("usb://1234:56z8", "expected " + protocol_usb.USAGE),
        ("usb://1234:5678/dev", "expected " + protocol_usb.USAGE),
        ("usb://1234:5678?serial", "expected " + protocol_usb.USAGE),
        ("usb://1234:5678?baud=9600", "unknown option 'baud' (known: endpoint, interface, out, serial, timeout_ms)"),
        ("usb://1234:5678?serial=", "serial=: expected a serial number"),
        ("usb://1234:5678?endpoint=0x01", "endpoint=0x01: expected an IN endpoint address 0x81-0x8f"),
        ("usb://1234:5678?out=0x81", "out=0x81: expected an OUT endpoint address 0x01-0x0f"),
        ("usb://1234:5678?interface=x", "interface=x: expected an interface number 0-255"),
        ("usb://1234:5678?timeout_ms=0", "timeout_ms=0: expected a whole number of milliseconds >= 1"),
    ],
)
def test_bad_urls(devices, url, reason):
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url(url)
    assert str(err.value) == f"{url}: {reason}"


def test_no_libusb_backend(monkeypatch):
    monkeypatch.setattr(protocol_usb, "BACKEND", None)
    for module in (usb.backend.libusb1, usb.backend.openusb, usb.backend.libusb0):
        monkeypatch.setattr(module, "get_backend", lambda *a, **k: None)
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("usb://1234:5678")
    assert str(err.value) == (
        "usb://1234:5678: no libusb backend available: install libusb 1.0, e.g. apt install libusb-1.0-0 or brew install libusb"
    )


def test_baud_rate_and_modem_lines_are_accepted(devices):
    devices(receiver())
    with serial.serial_for_url("usb://1234:5678", baudrate=9600, timeout=0) as port:
        port.baudrate = 115200
        port.rts = port.dtr = False
        assert port.cts and port.dsr and not port.ri and port.cd
        assert port.out_waiting == 0
