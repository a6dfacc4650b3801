"""Test helper: run arva-emulate in a subprocess and talk to its ptys with pyserial."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time

import serial


class EmulatorProcess:
    """``arva-emulate ARGS`` with ``--port pty``; ``ports`` maps stream label -> path."""

    def __init__(self, *args: str, streams: int = 1, timeout: float = 10.0) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "emulator.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            bufsize=0,  # unbuffered: select() then readline() must not swallow a second line
        )
        self.ports: dict[str, str] = {}
        deadline = time.monotonic() + timeout
        while len(self.ports) < streams:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self.proc.stdout], [], [], max(left, 0))
            if not ready:
                self.kill()
                raise TimeoutError(f"no pty announced within {timeout} s: {self.proc.stderr.read()!r}")
            line = self.proc.stdout.readline().decode()
            if not line:
                raise RuntimeError(f"emulator exited: {self.proc.wait()} {self.proc.stderr.read()!r}")
            label, path = line.split()
            self.ports[label] = path

    def open(self, label: str = "arva", timeout: float = 2.0) -> serial.Serial:
        return serial.Serial(self.ports[label], timeout=timeout)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        rc = self.proc.wait(timeout=timeout)
        return rc, self.proc.stderr.read().decode()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


def read_lines(ser: serial.Serial, count: int, timeout: float = 10.0) -> list[bytes]:
    """``count`` CR LF terminated lines, or fail after ``timeout`` seconds."""
    lines: list[bytes] = []
    deadline = time.monotonic() + timeout
    while len(lines) < count:
        if time.monotonic() > deadline:
            raise TimeoutError(f"got {len(lines)} of {count} lines")
        line = ser.read_until(b"\r\n")
        if line:
            lines.append(line)
    return lines


def process_rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS")


__all__ = ["EmulatorProcess", "read_lines", "process_rss_kb", "os"]
