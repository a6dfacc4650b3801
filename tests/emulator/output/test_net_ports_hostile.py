"""Hostile RFC 2217 clients (issue 29): none may grow the emulator without limit.

Each class runs against ``arva-emulate --port rfc2217-server:127.0.0.1:0`` in a
subprocess, over loopback, bounded in bytes (20 MB) and time (10 s); the emulator's
resident memory (VmRSS, /proc/PID/status) may grow at most :data:`RSS_CAP_KB` per hostile
client, the client is disconnected with one stderr line naming the cap, and a well-behaved
pyserial client is served afterwards. Plus, in process: the client cap, the cap on
reported line-setting changes, and the Telnet IAC escaping against pyserial's own.
"""

from __future__ import annotations

import io
import re
import socket
import struct
import sys
import threading
import time

import pytest
import serial
import serial.rfc2217
from hypothesis import given, settings
from hypothesis import strategies as st
from serial.serialutil import SerialBase

from emulator.output.net_ports import (
    MAX_CLIENTS,
    MAX_REPLIES_WAITING,
    MAX_SUBNEGOTIATION,
    NOTIFY_REFUSALS,
    NOTIFY_SETTING_CHANGES,
    ServerPort,
    escape_iac,
    parse_server_spec,
    stderr_notifier,
)
from emulator.testing import EmulatorProcess
from emulator.testing.harness import process_rss_kb

#: The issue's target: resident memory growth per hostile client.
RSS_CAP_KB = 8 * 1024
HOSTILE_BYTES = 20 << 20
HOSTILE_SECONDS = 10.0

IAC, SB, SE = b"\xff", b"\xfa", b"\xf0"
COM_PORT_OPTION, SET_BAUDRATE = b"\x2c", b"\x01"


def set_baudrate(baud: int) -> bytes:
    return IAC + SB + COM_PORT_OPTION + SET_BAUDRATE + struct.pack(">I", baud) + IAC + SE


def endpoint(url: str) -> tuple[str, int]:
    host, port = url.removeprefix("rfc2217://").rsplit(":", 1)
    return host, int(port)


def flood(address, first: bytes, unit: bytes) -> int:
    """Send ``first`` then ``unit`` repeatedly, never reading, until HOSTILE_BYTES are sent,
    HOSTILE_SECONDS have passed or the server hangs up; the bytes sent."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # and never read: replies pile up
    sock.settimeout(5)
    sock.connect(address)
    sock.settimeout(0.2)
    sent = 0
    deadline = time.monotonic() + HOSTILE_SECONDS
    try:
        sock.sendall(first)
        while sent < HOSTILE_BYTES and time.monotonic() < deadline:
            try:
                sent += sock.send(unit)
            except TimeoutError:
                continue
    except OSError:
        pass  # the server hung up on it
    finally:
        sock.close()
    return sent


def wait_for(emu: EmulatorProcess, pattern: str, timeout: float = 10.0) -> str:
    deadline = time.monotonic() + timeout
    while True:
        m = re.search(pattern, emu.stderr(), re.M)
        if m:
            return m.group(0)
        if time.monotonic() > deadline:
            return ""
        time.sleep(0.05)


HOSTILE = {
    # IAC SB COM-PORT-OPTION then bytes for ever, never IAC SE.
    "subnegotiation": (IAC + SB + COM_PORT_OPTION, b"A" * 65536,
                       rf"a Telnet subnegotiation longer than {MAX_SUBNEGOTIATION} bytes \(IAC SB without IAC SE\)"),
    # Requests answered (SET-BAUDRATE, the value in force), the answers never read.
    "unread replies": (b"", set_baudrate(115200) * 6554,
                       rf"more than {MAX_REPLIES_WAITING} bytes of RFC 2217 replies wait unread"),
}


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(90)
def test_hostile_clients_cost_the_emulator_at_most_8_mb_each():
    emu = EmulatorProcess("--port", "rfc2217-server:127.0.0.1:0", "--speed", "1")
    try:
        address = endpoint(emu.ports["arva"])
        with serial.serial_for_url(emu.ports["arva"], timeout=3) as warm:  # the first client's paths, warmed
            assert warm.read_until(b"\r\n").startswith(b"$PARVA,")
        growth = {}
        for name, (first, unit, reason) in HOSTILE.items():
            before = process_rss_kb(emu.proc.pid)
            sent = flood(address, first, unit)
            line = wait_for(emu, rf"^arva-emulate: arva: client 127\.0\.0\.1:\d+: {reason}; disconnecting$")
            growth[name] = process_rss_kb(emu.proc.pid) - before
            print(f"{name}: {sent} bytes sent, RSS +{growth[name]} kB")  # the figure of docs/reliability.md (-s)
            assert line, (name, sent, growth, emu.stderr()[-2000:])
            assert growth[name] <= RSS_CAP_KB, (name, sent, growth)
        # The emulator still serves a well-behaved client.
        with serial.serial_for_url(emu.ports["arva"], timeout=3) as ok:
            assert ok.read_until(b"\r\n").startswith(b"$PARVA,")
        rc, err = emu.stop()
        assert rc == 0
        assert err.count("; disconnecting\n") == len(HOSTILE)
    finally:
        emu.kill()


@pytest.mark.slow
def test_at_most_max_clients_are_served_and_refusals_are_counted():
    lines: list[str] = []
    port = ServerPort("arva", parse_server_spec("rfc2217-server:127.0.0.1:0"), notify=lines.append)
    address = endpoint(port.path)
    extra = NOTIFY_REFUSALS + 3
    socks = []
    try:
        for _ in range(MAX_CLIENTS):
            socks.append(socket.create_connection(address, timeout=5))
        deadline = time.monotonic() + 10
        while port.clients < MAX_CLIENTS:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        for _ in range(extra):
            with socket.create_connection(address, timeout=5) as refused:
                refused.settimeout(5)
                while refused.recv(4096):  # closed by the server at once: EOF
                    pass
        assert port.clients == MAX_CLIENTS and port.clients_refused == extra
    finally:
        for sock in socks:
            sock.close()
        port.close()
    refusals = [line for line in lines if " refused: " in line]
    assert len(refusals) == NOTIFY_REFUSALS
    assert re.fullmatch(rf"arva: client 127\.0\.0\.1:\d+ refused: {MAX_CLIENTS} clients are connected \(at most "
                        rf"{MAX_CLIENTS}\); further refusals only counted", refusals[-1])
    assert lines[-1] == f"arva: {extra} connections refused in all (at most {MAX_CLIENTS} clients at once)"


def test_line_setting_changes_are_reported_up_to_a_cap_then_counted():
    lines: list[str] = []
    port = ServerPort("arva", parse_server_spec("rfc2217-server:127.0.0.1:0"), notify=lines.append)
    changes = 500
    try:
        with socket.create_connection(endpoint(port.path), timeout=5) as sock:
            sock.settimeout(5)
            sock.sendall(b"".join(set_baudrate(9600 if k % 2 == 0 else 19200) for k in range(changes)))
            answers = b""
            while answers.count(IAC + SB + COM_PORT_OPTION + b"\x65") < changes:  # SET-BAUDRATE answers, all read
                chunk = sock.recv(65536)
                assert chunk, answers[-100:]
                answers += chunk
    finally:
        port.close()
    shown = [line for line in lines if " set line " in line]
    assert len(shown) == NOTIFY_SETTING_CHANGES
    assert lines[-1].endswith(f"left: 0 bytes sent, 0 dropped (line 19200 8N1), "
                              f"{changes - NOTIFY_SETTING_CHANGES} more line-setting changes not reported")


class _NoConnection:
    def write(self, data: bytes) -> None:
        pass


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300) | st.lists(st.sampled_from([b"\xff", b"$", b"\xff\xff", b"\r\n"])).map(b"".join))
def test_iac_escaping_is_pyserials(data):
    manager = serial.rfc2217.PortManager(SerialBase(), _NoConnection())
    assert escape_iac(data) == b"".join(manager.escape(data))


class _SlowStderr(io.RawIOBase):
    """A stderr pipe that takes its time (the GIL is released in every write, so the
    server's threads contend for it, as under load); keeps every byte."""

    def __init__(self) -> None:
        self.data = bytearray()

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        time.sleep(0.0002)
        self.data += bytes(b)
        return len(b)


def test_lines_from_the_servers_threads_never_share_a_stderr_line(monkeypatch):
    """Issue 29: client events from several threads sometimes merged onto one line."""
    raw = _SlowStderr()
    monkeypatch.setattr(sys, "stderr", io.TextIOWrapper(io.BufferedWriter(raw), line_buffering=True, write_through=True))
    notify = stderr_notifier("arva-emulate")
    threads, lines = 8, 150

    def events(i: int) -> None:
        for k in range(lines):
            notify(f"arva: client 127.0.0.1:{40000 + i} event {k}")

    workers = [threading.Thread(target=events, args=(i,)) for i in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(30)
    sys.stderr.flush()
    got = raw.data.decode().split("\n")
    assert got[-1] == ""
    pattern = re.compile(r"arva-emulate: arva: client 127\.0\.0\.1:400\d\d event \d+")
    assert [line for line in got[:-1] if not pattern.fullmatch(line)] == []
    assert len(got) - 1 == threads * lines
