"""arva-emulate on real ptys, read with pyserial (every read has a timeout)."""

import os
import pty
import signal
import subprocess
import sys
import time
from functools import reduce

import pytest
import serial
from scene_builders import link_faults_scene, one_tx, two_rx

from emulator.testing import EmulatorProcess, process_rss_kb, read_lines

pytestmark = pytest.mark.subprocess


def parva(seq, d=1905, delta=21, tx=1):
    body = f"PARVA,{seq},1,1,{tx},{d},{delta}".encode()
    return b"$%s*%02X\r\n" % (body, reduce(lambda a, b: a ^ b, body, 0))


@pytest.mark.pty
def test_exact_sentences_through_a_pty(scene_file):
    emu = EmulatorProcess("--scene", scene_file(one_tx(rate_hz=20.0)), "--port", "pty", "--frames", "8", "--delay", "1")
    try:
        with emu.open() as ser:
            assert read_lines(ser, 8) == [parva(k) for k in range(8)]
        rc, err = emu.stop()
        assert rc == 0
        assert err == "arva-emulate: 8 epochs sent (arva 8), 0 bytes dropped, 0 faults injected\n"
    finally:
        emu.kill()


@pytest.mark.pty
def test_several_receivers_each_on_its_own_pty(scene_file):
    emu = EmulatorProcess("--scene", scene_file(two_rx()), "--port", "pty", "--speed", "20", "--delay", "1", streams=2)
    try:
        assert sorted(emu.ports) == ["arva:1", "arva:7"]
        assert emu.ports["arva:1"] != emu.ports["arva:7"]
        with emu.open("arva:1") as a, emu.open("arva:7") as b:
            assert read_lines(a, 2) == [parva(0), parva(1)]
            # Receiver 7 at (10, 0, 0): transmitter 1 at (20, 5, 0) is 11.18 m away.
            first = read_lines(b, 1)[0]
            assert first.startswith(b"$PARVA,0,1,1,1,") and first != parva(0)
    finally:
        emu.kill()


def test_no_reader_never_blocks_and_memory_stays_flat(scene_file):
    def peak_rss(frames):
        emu = EmulatorProcess("--scene", scene_file(one_tx(rate_hz=1.0)), "--port", "pty", "--frames", str(frames), "--speed", "0")
        peak = 0
        while emu.proc.poll() is None:
            try:
                peak = max(peak, process_rss_kb(emu.proc.pid))
            except (FileNotFoundError, ProcessLookupError, RuntimeError):
                break
            time.sleep(0.02)
        rc, err = emu.stop()
        assert rc == 0
        return peak, err

    small, _ = peak_rss(50_000)
    big, err = peak_rss(400_000)
    assert big - small < 10_000, f"RSS grew from {small} kB to {big} kB"
    # Everything that did not fit the pty buffer was dropped and counted.
    sent = sum(len(parva(k % 65536)) for k in range(400_000))
    assert err.startswith("arva-emulate: 400000 epochs sent (arva 400000), ")
    dropped = int(err.split("), ")[1].split()[0])
    assert sent - 30_000 < dropped < sent  # only what fits the pty buffer was kept


@pytest.mark.pty
def test_reader_that_reopens_gets_fresh_epochs(scene_file):
    emu = EmulatorProcess("--scene", scene_file(one_tx(rate_hz=1.0)), "--port", "pty", "--speed", "50")
    try:
        with emu.open() as ser:
            line = read_lines(ser, 3)[-1]
            seq_closed = int(line.split(b",")[1])
        time.sleep(1.0)  # ~50 epochs written while nobody reads
        with emu.open() as ser:
            lines = read_lines(ser, 2)
        # pyserial flushes stale input on open; the first full line is fresh.
        seq_reopened = int(lines[-1].split(b",")[1])
        assert seq_reopened >= seq_closed + 40
    finally:
        emu.kill()


def test_link_dir_gets_stable_symlinks(scene_file, tmp_path):
    links = tmp_path / "links"
    links.mkdir()
    emu = EmulatorProcess("--scene", scene_file(two_rx()), "--port", "pty", "--link", str(links), "--speed", "1", streams=2)
    try:
        assert os.readlink(links / "arva-1") == emu.ports["arva:1"]
        assert os.readlink(links / "arva-7") == emu.ports["arva:7"]
        rc, err = emu.stop(signal.SIGINT)
        assert rc == 0 and err.startswith("arva-emulate: ")
        assert not (links / "arva-1").exists()  # removed on a clean stop
    finally:
        emu.kill()


def emulate(*args):
    return subprocess.run([sys.executable, "-m", "emulator.cli", *args], capture_output=True, timeout=30)


def test_missing_device_exit_2():
    proc = emulate("--port", "/dev/ttyNOPE0", "--frames", "1")
    assert proc.returncode == 2
    assert proc.stdout == b""
    assert proc.stderr == b"arva-emulate: port /dev/ttyNOPE0: no such device\n"


@pytest.mark.pty
def test_busy_device_exit_2():
    master, slave = pty.openpty()
    path = os.ttyname(slave)
    try:
        with serial.Serial(path, exclusive=True, timeout=0):
            proc = emulate("--port", path, "--frames", "1")
        assert proc.returncode == 2
        assert proc.stderr.decode() == f"arva-emulate: port {path}: device busy (another program has it open)\n"
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.pty
def test_writes_to_a_device_path(scene_file):
    master, slave = pty.openpty()
    path = os.ttyname(slave)
    try:
        proc = emulate("--scene", scene_file(one_tx(rate_hz=1.0)), "--port", path, "--frames", "3", "--speed", "0")
        assert proc.returncode == 0, proc.stderr
        data = os.read(master, 4096)
        assert data == parva(0) + parva(1) + parva(2)
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--stream", "gps=pty"], "arva-emulate: --stream gps=pty: no stream 'gps' in this scene (streams: arva)\n"),
        (["--stream", "gps"], None),
    ],
)
def test_stream_argument_errors(args, message):
    proc = emulate(*args, "--frames", "1")
    assert proc.returncode == 2
    if message:
        assert proc.stderr.decode() == message
    else:
        assert b"expected LABEL=PORT" in proc.stderr


def test_two_streams_cannot_share_stdout(scene_file):
    proc = emulate("--scene", scene_file(two_rx()), "--port", "-", "--frames", "1")
    assert proc.returncode == 2
    assert proc.stderr.decode() == (
        "arva-emulate: port -: 2 streams (arva:1, arva:7) cannot share stdout; use --port pty or --stream LABEL=PORT\n"
    )


UNPLUG = link_faults_scene(1, rate_hz=10.0, disconnect_every_s=1.0, disconnect_s=0.3)


@pytest.mark.pty
def test_pty_unplug_and_replug_follows_the_link(scene_file, tmp_path):
    links = tmp_path / "links"
    links.mkdir()
    emu = EmulatorProcess("--scene", scene_file(UNPLUG), "--port", "pty", "--link", str(links), "--frames", "25")
    try:
        with serial.Serial(str(links / "arva"), timeout=2) as ser:
            before = read_lines(ser, 2)
            assert all(line.startswith(b"$PARVA,") for line in before)
            # At scene time 1 s the device vanishes: the reader's port goes dead.
            with pytest.raises(serial.SerialException):
                for _ in range(40):
                    if not ser.read(100):
                        raise serial.SerialException("EOF")
        # ... and comes back 0.3 s later as a new pty, announced again on stdout (Linux
        # may hand out the same /dev/pts number again once the old one is free).
        line = emu.wait_announcement(2).split()
        assert line[0] == "arva" and line[1].startswith("/dev/pts/")
        assert os.readlink(links / "arva") == line[1]
        with serial.Serial(str(links / "arva"), timeout=2) as ser:
            seq = int(read_lines(ser, 2)[-1].split(b",")[1])
        assert seq >= 13  # resumed after the outage, epochs during it were lost
        rc, err = emu.stop()
        assert rc == 0 and " faults injected" in err and not err.endswith(" 0 faults injected\n")
    finally:
        emu.kill()


@pytest.mark.parametrize(
    "argv, line",
    [
        (["emulator.cli", "--port", "/dev/null", "--baud", "12345678901"],
         "arva-emulate: error: argument --baud: must be within 50..12000000, got 12345678901"),
        (["emulator.cli", "--port", "/dev/null", "--baud", "fast"],
         "arva-emulate: error: argument --baud: expected a whole number, got 'fast'"),
        (["bench.cli", "cat", "loop://", "--baud", "0"],
         "arva-bench: cat: argument --baud: must be within 50..12000000, got 0 (see arva-bench cat --help)"),
        (["bench.cli", "log", "--arva", "loop://", "--out", "unused", "--baud", "49"],
         "arva-bench log: error: argument --baud: must be within 50..12000000, got 49"),
    ],
)  # fmt: skip
def test_baud_out_of_range_is_a_one_line_error_not_a_traceback(argv, line):
    proc = subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, timeout=60)
    assert (proc.returncode, proc.stdout) == (2, "")
    assert proc.stderr.splitlines()[-1] == line
