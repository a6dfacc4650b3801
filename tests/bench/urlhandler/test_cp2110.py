"""pyserial's own cp2110:// handler (CP2110 HID UART bridges) over a fake ``hid`` module.

hidapi is not installed for the tests: the fake module stands in for it, so what runs
is pyserial's real handler, making the hidapi calls it makes on a real bridge.
"""

import sys
import time

import pytest
import serial

from fake_hid import FakeHid, HidDevice

pytestmark = [
    pytest.mark.timeout(10),
    # pyserial 3.5's reader thread still calls Thread.setDaemon() / setName()
    pytest.mark.filterwarnings("ignore:setDaemon:DeprecationWarning"),
    pytest.mark.filterwarnings("ignore:setName:DeprecationWarning"),
]

EPOCH = (
    b"$PARVA,0,4,1,4,761,-62*4C\r\n"
    b"$PARVA,0,4,2,2,926,0*5D\r\n"
    b"$PARVA,0,4,3,1,1905,21*5C\r\n"
    b"$PARVA,0,4,4,3,2808,-72*7D\r\n"
)
HANDLER = "serial.urlhandler.protocol_cp2110"


@pytest.fixture
def bridge(monkeypatch):
    """A CP2110 at /dev/hidraw3 behind a fake ``hid`` module (pyserial's handler re-imported)."""
    device = HidDevice(b"/dev/hidraw3", serial="0001A2B3")
    monkeypatch.setitem(sys.modules, "hid", FakeHid(device, HidDevice(b"0001:0023:00", serial="0002")))
    sys.modules.pop(HANDLER, None)  # so that it binds the fake module
    yield device
    sys.modules.pop(HANDLER, None)


def read_exactly(port, n):
    data = b""
    while len(data) < n:
        chunk = port.read(n - len(data))
        assert chunk, f"timed out after {len(data)} of {n} bytes"
        data += chunk
    return data


def test_open_configures_and_enables_the_uart(bridge):
    with serial.serial_for_url("cp2110:///dev/hidraw3", baudrate=115200, timeout=1):
        assert bridge.is_open
        assert bridge.feature_reports == [
            bytes.fromhex("50 0001c200 00 00 03 00"),  # 115200 Bd, no parity, no flow control, 8 bits, 1 stop
            bytes.fromhex("41 01"),  # UART enable
            bytes.fromhex("52 00"),  # stop line break
        ]
        assert bridge.uart_enabled and bridge.uart_config == (115200, 0, 0, 3, 0)
    assert not bridge.is_open


def test_uart_settings_reach_the_bridge(bridge):
    with serial.serial_for_url("cp2110:///dev/hidraw3", baudrate=9600, parity="E", stopbits=2, timeout=1):
        assert bridge.uart_config == (9600, 2, 0, 3, 1)


@pytest.mark.parametrize("chunk", [63, 20, 1])
def test_reads_the_exact_sentences(bridge, chunk):
    stream = EPOCH * 5
    with serial.serial_for_url("cp2110:///dev/hidraw3", timeout=1) as port:
        bridge.receive(stream, chunk=chunk)
        assert read_exactly(port, len(stream)) == stream
        t0 = time.monotonic()
        port.timeout = 0.2
        assert port.read(10) == b""
        assert 0.15 <= time.monotonic() - t0 < 1
    # the reader thread polls with 64-byte reads of at most 100 ms
    assert set(bridge.reads) == {(64, 100)}


def test_read_returns_whole_reports(bridge):
    """pyserial's cp2110 read(size) returns whole HID reports, so it may exceed SIZE:
    read with read(in_waiting or N) and split lines yourself, not with readline()."""
    with serial.serial_for_url("cp2110:///dev/hidraw3", timeout=1) as port:
        bridge.receive(EPOCH[:40], chunk=40)
        assert port.read(1) == EPOCH[:40]


def test_libusb_style_path(bridge):
    other = sys.modules["hid"].devices[1]
    with serial.serial_for_url("cp2110://0001:0023:00", timeout=1) as port:
        assert other.is_open and not bridge.is_open
        other.receive(EPOCH)
        assert read_exactly(port, len(EPOCH)) == EPOCH


def test_writes_are_split_into_reports(bridge):
    data = b"$PCMD,RATE,10*00\r\n" * 6  # 108 bytes: two reports (63 + 45)
    with serial.serial_for_url("cp2110:///dev/hidraw3", timeout=1) as port:
        port.write(data)
    assert bytes(bridge.tx) == data


def test_reset_input_buffer_purges_the_fifo(bridge):
    with serial.serial_for_url("cp2110:///dev/hidraw3", timeout=0.3) as port:
        port.reset_input_buffer()
        assert bridge.feature_reports[-1] == bytes.fromhex("43 02")


def test_missing_bridge(bridge):
    with pytest.raises(serial.SerialException) as err:
        serial.serial_for_url("cp2110:///dev/hidraw9")
    # pyserial passes the errno of hidapi's OSError, which is None
    assert str(err.value) == "[Errno None] could not open port cp2110:///dev/hidraw9: open failed"


def test_without_hidapi_the_url_names_the_extra_not_an_unknown_protocol(monkeypatch, tmp_path, capsys):
    from bench.cli import main
    from bench.transport import check_url, open_device
    from firmware_proto.errors import MissingExtra

    monkeypatch.setitem(sys.modules, "hid", None)  # as if the extra were not installed
    sys.modules.pop(HANDLER, None)
    why = "a cp2110:// device needs hidapi (install the extra: pip install 'arva-bench[hid]')"
    with pytest.raises(MissingExtra) as err:
        open_device("cp2110:///dev/hidraw3")
    assert str(err.value) == why
    check_url("loop://")  # schemes without an extra pass
    check_url("/dev/ttyUSB0")
    assert main(["cat", "CP2110:///dev/hidraw3"]) == 2
    assert capsys.readouterr().err == f"arva-bench: cat: CP2110:///dev/hidraw3: {why}\n"
    assert main(["log", "--arva", "loop://", "--gps", "cp2110:///dev/hidraw3", "--out", str(tmp_path / "s")]) == 2
    assert capsys.readouterr().err == f"arva-bench: {why}\n"
    assert not (tmp_path / "s").exists()
