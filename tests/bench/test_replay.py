"""arva-bench replay: logged bytes back on ptys, byte for byte, with their timing."""

import subprocess
import sys
import time

import pytest
import serial

from bench.session import SessionWriter

pytestmark = pytest.mark.subprocess


def make_session(path):
    w = SessionWriter(path, {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"},
                                         "gps-rx": {"kind": "gps", "url": "y", "role": "rx"}}})
    arva = [b"$PARVA,%d,1,1,-1,-1,-1*%02X\r\n" % (k, 0) for k in range(5)]
    for k in range(5):
        w.raw("arva", arva[k][:10], mono=100.0 + 0.2 * k, utc=0.0)  # split reads, as logged
        w.raw("arva", arva[k][10:], mono=100.0 + 0.2 * k + 0.01, utc=0.0)
        w.raw("gps-rx", b"gps%d\r\n" % k, mono=100.1 + 0.2 * k, utc=0.0)
    w.close()
    return b"".join(arva)


@pytest.mark.pty
@pytest.mark.timeout(30)
def test_replay_byte_for_byte_with_timing(tmp_path):
    expected = make_session(tmp_path / "s")
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), "--delay", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0,
    )
    ports = dict(proc.stdout.readline().decode().split() for _ in range(2))
    with serial.Serial(ports["arva"], timeout=2) as a, serial.Serial(ports["gps-rx"], timeout=2) as g:
        t0 = time.monotonic()
        got = b""
        while len(got) < len(expected):
            chunk = a.read(len(expected) - len(got))
            assert chunk, "timed out"
            got += chunk
        elapsed = time.monotonic() - t0
        gps = b"".join(g.read_until(b"\r\n") for _ in range(5))
    assert got == expected
    assert gps == b"".join(b"gps%d\r\n" % k for k in range(5))
    assert 0.7 < elapsed < 2.0  # 0.81 s of recorded time after the 1 s delay
    assert proc.wait(timeout=10) == 0
    assert proc.stderr.read() == b"arva-bench: replay: 15 reads, %d bytes written, 0 bytes dropped\n" % (
        len(expected) + len(gps)
    )


def test_replay_to_stdout_as_fast_as_possible(tmp_path):
    expected = make_session(tmp_path / "s")
    proc = subprocess.run(
        [sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), "--device", "arva=-", "--speed", "0"],
        capture_output=True, timeout=30,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == expected  # the gps-rx pty is announced on stderr: stdout carries data
    assert proc.stderr.startswith(b"gps-rx /dev/pts/")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--device", "nope=-"], "arva-bench: replay: --device nope=-: expected NAME=PORT with NAME one of arva, gps-rx\n"),
        (["--speed", "-1"], "arva-bench replay: error: argument --speed: must be 0 (as fast as possible) or within 1e-06..1e+06, got -1\n"),
    ],
)
def test_replay_errors(tmp_path, args, message):
    make_session(tmp_path / "s")
    proc = subprocess.run([sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), *args],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2 and proc.stderr == message


def test_replay_not_a_session(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "bench.cli", "replay", str(tmp_path)], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert proc.stderr == f"arva-bench: {tmp_path}: not a session directory (no manifest.json)\n"


def test_replay_of_a_session_killed_in_its_first_write(tmp_path):
    w = SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"}}})
    w.close()
    (tmp_path / "s" / "arva.raw").write_bytes(b"100.0\t1970-01-01T00:00:00.000000Z\tJFBBUl")  # torn, no newline
    proc = subprocess.run([sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), "--speed", "0"],
                          capture_output=True, text=True, timeout=30)  # fmt: skip
    assert (proc.returncode, proc.stdout) == (2, "")
    assert proc.stderr == f"arva-bench: replay: {tmp_path / 's'}: no complete read in any device's raw log\n"


def test_replay_opens_ports_with_the_emulators_factory(tmp_path):
    """One port factory (emulator.output.factory): a regular file is a port in replay as
    in arva-emulate, and --link DIR is created on a fresh machine, as arva-emulate does."""
    expected = make_session(tmp_path / "s")
    links = tmp_path / "fresh" / "links"
    proc = subprocess.run(
        [sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), "--speed", "0",
         "--device", f"arva={tmp_path / 'arva.out'}", "--link", str(links)],
        capture_output=True, text=True, timeout=30,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "arva.out").read_bytes() == expected
    name, path = proc.stdout.split()
    assert name == "gps-rx" and links.is_dir() and not (links / "gps-rx").exists()  # removed at close
    assert proc.stderr == "arva-bench: replay: 15 reads, %d bytes written, 0 bytes dropped\n" % (len(expected) + 30)
