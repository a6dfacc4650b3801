"""emulator.output.factory: every port spec opened in one place, for arva-emulate and
arva-bench replay alike."""

import pytest

from emulator.output.factory import PortOptions, link_path, open_port
from emulator.output.net_ports import LineSettings, ServerPort
from emulator.output.ports import FilePort, PtyPort, SerialPort, StdoutPort
from firmware_proto.errors import InputError


@pytest.mark.pty
def test_each_spec_kind(tmp_path):
    assert type(open_port("arva", "-")) is StdoutPort
    with open_port("gps:rx", "pty", PortOptions(link_dir=tmp_path / "l")) as pty:
        assert type(pty) is PtyPort
        assert (tmp_path / "l" / "gps-rx").resolve() == __import__("pathlib").Path(pty.path).resolve()
    assert not (tmp_path / "l" / "gps-rx").exists()  # the context closed the port and its link
    with open_port("arva", str(tmp_path / "out.txt")) as f:
        assert type(f) is FilePort
        assert f.write(b"abc") == 3
    assert (tmp_path / "out.txt").read_bytes() == b"abc"
    with open_port("arva", "loop://", PortOptions(line=LineSettings(9600, 7, "E", 2))) as s:
        assert type(s) is SerialPort
        assert (s._serial.baudrate, s._serial.bytesize, s._serial.parity, s._serial.stopbits) == (9600, 7, "E", 2)
    server = open_port("arva", "tcp-server:127.0.0.1:0")
    try:
        assert type(server) is ServerPort
    finally:
        server.close()


def test_serial_options():
    opts = PortOptions(line=LineSettings(57600, 8, "N", 1), rtscts=True)
    assert opts.serial_options("/dev/ttyUSB0") == {
        "baudrate": 57600, "bytesize": 8, "parity": "N", "stopbits": 1, "rtscts": True, "xonxoff": False, "exclusive": True,
    }
    assert "exclusive" not in opts.serial_options("loop://")


def test_link_dir_that_is_a_file(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError) as err:
        link_path(tmp_path / "f", "arva")
    assert str(err.value) == f"--link {tmp_path / 'f'}: not a directory"
    assert link_path(None, "arva") is None
