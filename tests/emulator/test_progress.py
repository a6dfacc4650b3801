"""Progress bars: drawn on stderr only when it is a terminal; stdout and pipes unchanged."""

from __future__ import annotations

import io
import os
import pty
import select
import subprocess
import sys
import time

import pytest

from bench.session import SessionWriter
from emulator.progress import Tracker, progress

SWEEP = [sys.executable, "-m", "emulator.closed_loop.sweep", "--n", "1", "--strategies", "flux", "--workers", "1",
         "--t-max", "60"]


def run_with_stderr_on_a_pty(cmd: list[str], timeout: float = 60.0) -> tuple[int, bytes, bytes]:
    """(exit status, stdout from a pipe, what the pty's terminal saw on stderr)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    seen = b""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no end of output within {timeout} s: {seen[-300:]!r}"
        ready, _, _ = select.select([master], [], [], left)
        if not ready:
            continue
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: every slave descriptor closed (the process ended)
            break
        if not chunk:
            break
        seen += chunk
    os.close(master)
    out = proc.stdout.read()
    return proc.wait(timeout=timeout), out, seen


def test_no_terminal_no_bar():
    sink = io.StringIO()
    with progress("work", total=4, unit="runs", stream=sink) as bar:
        assert type(bar) is Tracker and not bar.enabled
        bar.advance(3, note="x")
        bar.update(completed=4)
    assert sink.getvalue() == ""


def test_a_forced_bar_renders_counts_and_note():
    sink = io.StringIO()
    with progress("work", total=4, unit="runs", stream=sink, enabled=True) as bar:
        bar.advance(3, note="12x real time")
    text = sink.getvalue()
    assert "work" in text and "3/4 runs" in text and "12x real time" in text


@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.timeout(120)
def test_sweep_progress_on_a_terminal_only():
    rc, out_tty, seen = run_with_stderr_on_a_pty(SWEEP)
    assert rc == 0
    assert b"arva-sweep" in seen and b"1/1 runs" in seen and b"x real time" in seen and b"ETA" in seen
    piped = subprocess.run(SWEEP, capture_output=True, timeout=120)
    assert piped.returncode == 0
    assert piped.stdout == out_tty  # stdout is the same table either way
    assert b"\x1b" not in piped.stderr and b"runs  " not in piped.stderr
    assert piped.stderr.count(b"\n") == 1 and piped.stderr.startswith(b"1 runs, 60 s of scene time in ")


@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.timeout(120)
def test_replay_progress_on_a_terminal_only(tmp_path):
    w = SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"}}})
    data = [b"$PARVA,%d,1,1,-1,-1,-1*00\r\n" % k for k in range(50)]
    for k, line in enumerate(data):
        w.raw("arva", line, mono=100.0 + k, utc=0.0)  # 49 s of session time
    w.close()
    cmd = [sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"), "--device", "arva=-", "--speed", "0"]
    rc, out, seen = run_with_stderr_on_a_pty(cmd)
    assert rc == 0
    assert out == b"".join(data)
    assert b"replay" in seen and b"/49 s of session" in seen
    piped = subprocess.run(cmd, capture_output=True, timeout=60)
    assert piped.stdout == b"".join(data)
    assert piped.stderr == b"arva-bench: replay: 50 reads, %d bytes written, 0 bytes dropped\n" % len(b"".join(data))
