"""The in-process pyserial URL handler arvaemu:// (no pty, no thread)."""

import time

import pytest
import serial
import serial.threaded
from scene_builders import two_rx

import emulator.urlhandler  # noqa: F401  (registers arvaemu://)

DEFAULT_EPOCH_0 = (
    b"$PARVA,0,4,1,4,761,-62*4C\r\n"
    b"$PARVA,0,4,2,2,926,0*5D\r\n"
    b"$PARVA,0,4,3,1,1905,21*5C\r\n"
    b"$PARVA,0,4,4,3,2808,-72*7D\r\n"
)


def test_default_scene_as_fast_as_read():
    with serial.serial_for_url("arvaemu://?speed=0&frames=2", timeout=1) as port:
        data = port.read(10_000)
    assert data.startswith(DEFAULT_EPOCH_0)
    assert data.count(b"\r\n") == 8 and data.endswith(b"$PARVA,1,4,4,3,2808,-72*7C\r\n")


@pytest.mark.subprocess
def test_same_bytes_as_the_command_line():
    import subprocess
    import sys

    cli = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--frames", "300", "--speed", "0"], capture_output=True, timeout=60
    ).stdout
    with serial.serial_for_url("arvaemu://default?speed=0&frames=300", timeout=1) as port:
        chunks = []
        while chunk := port.read(777):
            chunks.append(chunk)
    assert b"".join(chunks) == cli


def test_real_time_pacing_and_readline():
    with serial.serial_for_url("arvaemu://?speed=20", timeout=2) as port:
        t0 = time.monotonic()
        lines = [port.readline() for _ in range(12)]  # epochs 0, 1, 2 (4 slots each)
        elapsed = time.monotonic() - t0
    assert lines[:4] == DEFAULT_EPOCH_0.splitlines(keepends=True)
    assert [line.split(b",")[1] for line in lines] == [b"0"] * 4 + [b"1"] * 4 + [b"2"] * 4
    assert 0.09 <= elapsed < 1.0  # epoch 2 is due 100 ms after opening


def test_non_blocking_read_returns_what_is_due():
    with serial.serial_for_url("arvaemu://?speed=1", timeout=0) as port:
        first = port.read(4096)
        assert first == DEFAULT_EPOCH_0
        assert port.read(4096) == b""  # epoch 1 is 1 s away
        assert port.in_waiting == 0


def test_receiver_selection(scene_file):
    scene = scene_file(two_rx(channels_7=2), "two.toml")
    with serial.serial_for_url(f"arvaemu://{scene}?receiver=7&speed=0&frames=1", timeout=1) as port:
        data = port.read(1000)
    assert data.splitlines()[1] == b"$PARVA,0,2,2,-1,-1,-1*78"
    assert data.startswith(b"$PARVA,0,2,1,1,")


def test_frames_then_eof():
    with serial.serial_for_url("arvaemu://?speed=0&frames=1", timeout=0.2) as port:
        assert port.read(10_000) == DEFAULT_EPOCH_0
        t0 = time.monotonic()
        assert port.read(1) == b""
        assert time.monotonic() - t0 < 0.1  # ended: no waiting for the timeout


def test_reader_thread_protocol():
    got = []

    class Lines(serial.threaded.LineReader):
        def handle_line(self, line):
            got.append(line)

    port = serial.serial_for_url("arvaemu://?speed=50", timeout=0.05)
    with serial.threaded.ReaderThread(port, Lines):
        deadline = time.monotonic() + 5
        while len(got) < 8 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert got[:4] == [line.decode() for line in DEFAULT_EPOCH_0.split(b"\r\n")[:4]]


@pytest.mark.parametrize(
    "url, message",
    [
        ("arvaemu://?sped=1", "arvaemu://?sped=1: unknown option 'sped' (known: delay, frames, receiver, speed)"),
        ("arvaemu://?speed=-1", "arvaemu://?speed=-1: speed=-1: must be 0 (as fast as possible) or within 1e-06..1e+06, got -1"),
        ("arvaemu://?speed=1e7", "arvaemu://?speed=1e7: speed=1e7: must be 0 (as fast as possible) or within 1e-06..1e+06, got 1e7"),
        ("arvaemu://?frames=2.5", "arvaemu://?frames=2.5: frames=2.5: expected a whole number, got '2.5'"),
        ("arvaemu://?delay=-1", "arvaemu://?delay=-1: delay=-1: must be >= 0, got -1"),
        ("arvaemu://?receiver=3", "arvaemu://?receiver=3: receiver=3: no such receiver (ids: [1])"),
        ("arvaemu://nope.toml", "nope.toml: cannot read: No such file or directory"),
    ],
)
def test_bad_urls(url, message):
    with pytest.raises(serial.SerialException) as info:
        serial.serial_for_url(url)
    assert str(info.value) == message



def test_parse_url_reads_scene_receiver_and_options(scene_file):
    from emulator.urlhandler.protocol_arvaemu import parse_url

    scene = scene_file(two_rx(channels_7=2), "two.toml")
    u = parse_url(f"arvaemu://{scene}?receiver=7&speed=0&frames=3&delay=0.5")
    assert (u.index, u.speed, u.frames, u.delay) == (1, 0.0, 3, 0.5)
    assert [rx.id for rx in u.scene.receivers] == [1, 7]
    with pytest.raises(serial.SerialException, match=r"receiver=9: no such receiver \(ids: \[1, 7\]\)"):
        parse_url(f"arvaemu://{scene}?receiver=9")
