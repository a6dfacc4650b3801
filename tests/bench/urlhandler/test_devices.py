"""``arva-bench devices``: fake serial ports, a fake hid module and a fake USB backend."""

import json
import sys

import pytest
import serial
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

import bench.urlhandler  # noqa: F401  (registers usb://)
from bench import cli, devices
from bench.urlhandler import protocol_usb
from fake_hid import FakeHid, HidDevice
from fake_usb import FakeBackend, FakeDevice

pytestmark = [
    pytest.mark.timeout(10),
    pytest.mark.filterwarnings("ignore:setDaemon:DeprecationWarning"),  # pyserial 3.5's cp2110 thread
    pytest.mark.filterwarnings("ignore:setName:DeprecationWarning"),
]

HID_MISSING = "HID: not listed (install the extra: pip install 'arva-bench[hid]')"
UDEV = "USB: some devices could not be opened: on Linux, a udev rule grants access: see docs/transports.md"


def port(device, vid=None, pid=None, serial_number=None, manufacturer=None, description="n/a"):
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number = vid, pid, serial_number
    info.manufacturer, info.description = manufacturer, description
    return info


PORTS = [
    port("/dev/ttyUSB10", 0x0403, 0x6001, "A10K2B3C", "FTDI", "FT232R USB UART"),
    port("/dev/ttyS0"),
    port("/dev/ttyUSB0", 0x10C4, 0xEA60, "0001", "Silicon Labs", "CP2102 USB to UART Bridge Controller"),
    port("/dev/ttyUSB2", 0x0403, 0x6001, "A20K2B3C", "FTDI", "FT232R USB UART"),
]


def hid_module():
    return FakeHid(
        HidDevice(b"/dev/hidraw3", serial="0001A2B3"),
        HidDevice(b"/dev/hidraw3", serial="0001A2B3", usage=2),  # same device, another usage
        HidDevice(b"/dev/hidraw0", vid=0x046D, pid=0xC077, serial="", product="USB Optical Mouse", manufacturer="Logitech"),
        HidDevice(b"0003:0005:00", vid=0x10C4, pid=0xEAB0, serial="", product="CP2114", manufacturer=""),
    )


def usb_backend():
    return FakeBackend(
        FakeDevice(0x1234, 0x5678, serial="RX 7", product="ARVA receiver", manufacturer="ACME", bus=2, address=3),
        FakeDevice(0x1D6B, 0x0002, product="xHCI Host Controller", device_class=0x09, bus=1, address=1),
        FakeDevice(0x0BDA, 0x8153, serial="X", access_denied=True, bus=1, address=7),
        FakeDevice(0x10C4, 0xEA80, serial="0001A2B3", product="CP2110 HID USB-to-UART Bridge",
                   manufacturer="Silicon Laboratories", bus=1, address=5),
        FakeDevice(0x10C4, 0xEA60, serial="0001", product="CP2102 USB to UART Bridge Controller",
                   manufacturer="Silicon Labs", bus=1, address=4),
        FakeDevice(0x2341, 0x8036, product="Leonardo", bus=1, address=9),
    )


@pytest.fixture
def machine(monkeypatch):
    """Fake serial ports, HID devices and USB devices; returns the fake hid module."""
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: list(PORTS))
    hid = hid_module()
    monkeypatch.setitem(sys.modules, "hid", hid)
    sys.modules.pop("serial.urlhandler.protocol_cp2110", None)
    monkeypatch.setattr(protocol_usb, "BACKEND", usb_backend())
    yield hid
    sys.modules.pop("serial.urlhandler.protocol_cp2110", None)


def run(capsys, *argv):
    status = cli.main(["devices", *argv])
    out, err = capsys.readouterr()
    return status, out, err


TABLE = """\
KIND    URL                              VID:PID    SERIAL    DESCRIPTION
serial  /dev/ttyS0                       -          -         -
serial  /dev/ttyUSB0                     10c4:ea60  0001      Silicon Labs CP2102 USB to UART Bridge Controller
serial  /dev/ttyUSB2                     0403:6001  A20K2B3C  FTDI FT232R USB UART
serial  /dev/ttyUSB10                    0403:6001  A10K2B3C  FTDI FT232R USB UART
hid     cp2110://0003:0005:00            10c4:eab0  -         CP2114
hid     -                                046d:c077  -         Logitech USB Optical Mouse
hid     cp2110:///dev/hidraw3            10c4:ea80  0001A2B3  Silicon Laboratories CP2110 HID USB-to-UART Bridge
usb     usb://10c4:ea60?serial=0001      10c4:ea60  0001      Silicon Labs CP2102 USB to UART Bridge Controller (also /dev/ttyUSB0)
usb     usb://10c4:ea80?serial=0001A2B3  10c4:ea80  0001A2B3  Silicon Laboratories CP2110 HID USB-to-UART Bridge (also cp2110:///dev/hidraw3)
usb     usb://0bda:8153                  0bda:8153  -         - (strings unreadable: Access denied (insufficient permissions))
usb     usb://2341:8036                  2341:8036  -         Leonardo
usb     usb://1234:5678?serial=RX%207    1234:5678  RX 7      ACME ARVA receiver
"""


def obj(kind, url, vid, pid, serial_number, manufacturer, description, device, note=None):
    return dict(
        kind=kind, url=url, vid=vid, pid=pid, serial_number=serial_number, manufacturer=manufacturer,
        description=description, device=device, note=note,
    )


JSON = [
    obj("serial", "/dev/ttyS0", None, None, None, None, None, "/dev/ttyS0"),
    obj("serial", "/dev/ttyUSB0", "10c4", "ea60", "0001", "Silicon Labs", "CP2102 USB to UART Bridge Controller",
        "/dev/ttyUSB0"),
    obj("serial", "/dev/ttyUSB2", "0403", "6001", "A20K2B3C", "FTDI", "FT232R USB UART", "/dev/ttyUSB2"),
    obj("serial", "/dev/ttyUSB10", "0403", "6001", "A10K2B3C", "FTDI", "FT232R USB UART", "/dev/ttyUSB10"),
    obj("hid", "cp2110://0003:0005:00", "10c4", "eab0", None, None, "CP2114", "0003:0005:00"),
    obj("hid", None, "046d", "c077", None, "Logitech", "USB Optical Mouse", "/dev/hidraw0"),
    obj("hid", "cp2110:///dev/hidraw3", "10c4", "ea80", "0001A2B3", "Silicon Laboratories",
        "CP2110 HID USB-to-UART Bridge", "/dev/hidraw3"),
    obj("usb", "usb://10c4:ea60?serial=0001", "10c4", "ea60", "0001", "Silicon Labs",
        "CP2102 USB to UART Bridge Controller", "bus 1 address 4", "also /dev/ttyUSB0"),
    obj("usb", "usb://10c4:ea80?serial=0001A2B3", "10c4", "ea80", "0001A2B3", "Silicon Laboratories",
        "CP2110 HID USB-to-UART Bridge", "bus 1 address 5", "also cp2110:///dev/hidraw3"),
    obj("usb", "usb://0bda:8153", "0bda", "8153", None, None, None, "bus 1 address 7",
        "strings unreadable: Access denied (insufficient permissions)"),
    obj("usb", "usb://2341:8036", "2341", "8036", None, None, "Leonardo", "bus 1 address 9"),
    obj("usb", "usb://1234:5678?serial=RX%207", "1234", "5678", "RX 7", "ACME", "ARVA receiver", "bus 2 address 3"),
]


def test_table(machine, capsys):
    status, out, err = run(capsys)
    assert status == 0
    assert out == TABLE
    assert err == UDEV + "\n"


def test_json(machine, capsys):
    status, out, err = run(capsys, "--json")
    assert status == 0
    assert out.count("\n") == 1  # one JSON array on one line
    assert json.loads(out) == JSON
    assert err == UDEV + "\n"


@pytest.mark.slow
def test_the_urls_open_the_devices(machine, capsys):
    _, out, _ = run(capsys, "--json")
    urls = {(row["kind"], row["description"]): row["url"] for row in json.loads(out)}
    bridge = machine.devices[0]
    with serial.serial_for_url(urls["hid", "CP2110 HID USB-to-UART Bridge"], timeout=1) as port:
        assert bridge.is_open
        bridge.receive(b"$PARVA,0,4,2,2,926,0*5D\r\n")
        assert port.read(26) == b"$PARVA,0,4,2,2,926,0*5D\r\n"
    receiver = protocol_usb.BACKEND.devices[0]
    receiver.feed(b"$PARVA,0,4,1,4,761,-62*4C\r\n")
    with serial.serial_for_url(urls["usb", "ARVA receiver"], timeout=1) as port:  # serial=RX%207 unescaped
        assert port.readline() == b"$PARVA,0,4,1,4,761,-62*4C\r\n"


def test_hid_extra_not_installed(machine, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "hid", None)  # import hid raises ImportError
    status, out, err = run(capsys)
    assert status == 0
    assert err.splitlines() == [HID_MISSING, UDEV]
    assert [line.split()[0] for line in out.splitlines()] == ["KIND"] + ["serial"] * 4 + ["usb"] * 5
    assert "also cp2110" not in out and "(also /dev/ttyUSB0)" in out


def test_hidapi_failure_is_one_line(machine, monkeypatch, capsys):
    def broken(*args, **kwargs):
        raise OSError("hid_init failed")

    monkeypatch.setattr(machine, "enumerate", broken)
    status, out, err = run(capsys)
    assert status == 0 and "hid " not in out
    assert err.splitlines()[0] == "HID: not listed (hidapi failed: hid_init failed)"


def test_no_libusb_backend(machine, monkeypatch, capsys):
    monkeypatch.setattr(protocol_usb, "BACKEND", None)
    for module in (usb.backend.libusb1, usb.backend.openusb, usb.backend.libusb0):
        monkeypatch.setattr(module, "get_backend", lambda *a, **k: None)
    status, out, err = run(capsys)
    assert status == 0
    assert err == (
        "USB: not listed (no libusb backend available: install libusb 1.0, e.g. apt install libusb-1.0-0"
        " or brew install libusb)\n"
    )
    expected = [line.split() for line in TABLE.splitlines() if not line.startswith("usb")]
    assert [line.split() for line in out.splitlines()] == expected  # same rows, narrower URL column


def test_pyusb_not_installed(machine, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "usb", None)
    monkeypatch.setitem(sys.modules, "usb.core", None)
    status, out, err = run(capsys)
    assert status == 0
    assert err == "USB: not listed (install the extra: pip install 'arva-bench[usb]')\n"
    assert out.splitlines()[-1].startswith("hid ")


def test_str_hid_paths(monkeypatch, capsys):
    hid = FakeHid(HidDevice(b"/dev/hidraw1", serial="7"))
    info = hid.devices[0].info()
    monkeypatch.setattr(hid, "enumerate", lambda *a, **k: [dict(info, path="/dev/hidraw1")])
    monkeypatch.setitem(sys.modules, "hid", hid)
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: [])
    monkeypatch.setattr(protocol_usb, "BACKEND", FakeBackend())
    _, out, _ = run(capsys)
    assert out.splitlines()[1].split()[:4] == ["hid", "cp2110:///dev/hidraw1", "10c4:ea80", "7"]


def test_nothing_found(monkeypatch, capsys):
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: [])
    monkeypatch.setitem(sys.modules, "hid", FakeHid())
    monkeypatch.setattr(protocol_usb, "BACKEND", FakeBackend())
    assert run(capsys) == (0, "", "no devices found\n")
    assert run(capsys, "--json") == (0, "[]\n", "")


@pytest.mark.parametrize(
    "path, url",
    [
        (b"/dev/hidraw3", "cp2110:///dev/hidraw3"),  # Linux hidraw
        (b"0001:0023:00", "cp2110://0001:0023:00"),  # hidapi's libusb backend
        (b"DevSrvsID:4294969490", "cp2110://DevSrvsID:4294969490"),  # macOS
        (b"\\\\?\\hid#vid_10c4&pid_ea80#7&1b2c&0&0000#{4d1e55b2-f16f-11cf-88cb-001111000030}", None),  # Windows
        (b"\xff\xfe", None),
    ],
)
def test_cp2110_url_round_trips_or_is_none(path, url):
    assert devices.cp2110_url(path) == url


def test_unprintable_strings_do_not_break_the_table(monkeypatch, capsys):
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: [port("/dev/ttyACM0", 1, 2, "S\x1b[2J", None, "X\tY")])
    monkeypatch.setitem(sys.modules, "hid", FakeHid())
    monkeypatch.setattr(protocol_usb, "BACKEND", FakeBackend())
    _, out, _ = run(capsys)
    assert out.splitlines()[1] == "serial  /dev/ttyACM0  0001:0002  S?[2J   X?Y"
