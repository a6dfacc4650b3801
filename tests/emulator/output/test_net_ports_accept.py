"""ServerPort's accept loop blocks (no polling) and wakes at once on close; the Telnet
IAC escaping is pyserial's PortManager.escape, byte-identical to doubling every 0xFF,
on the wire as a raw RFC 2217 client sees it."""

from __future__ import annotations

import socket
import time

import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.output.net_ports import ServerPort, escape_iac, parse_server_spec


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200) | st.lists(st.sampled_from([b"\xff", b"$PARVA", b"\xff\xff", b"\r\n"])).map(b"".join))
def test_escaping_doubles_every_iac_and_nothing_else(data):
    assert escape_iac(data) == data.replace(b"\xff", b"\xff\xff")


def _wait(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_close_wakes_the_blocked_accept_loop_at_once():
    """Before, accept() polled every 0.2 s: close() took up to 0.2 s per port."""
    took = []
    for kind in ("tcp-server", "rfc2217-server"):
        for _ in range(3):
            port = ServerPort("arva", parse_server_spec(f"{kind}:127.0.0.1:0"))
            time.sleep(0.05)  # the acceptor is blocked in select
            t0 = time.monotonic()
            port.close()
            took.append(time.monotonic() - t0)
            assert not port._acceptor.is_alive()
    assert max(took) < 0.1, took


def test_a_client_is_accepted_and_a_closed_port_refuses_connections():
    port = ServerPort("arva", parse_server_spec("tcp-server:127.0.0.1:0"))
    host, number = port.path.removeprefix("socket://").rsplit(":", 1)
    with socket.create_connection((host, int(number)), timeout=5) as sock:
        _wait(lambda: port.clients == 1)
        port.write(b"$PARVA\r\n")
        sock.settimeout(5)
        assert sock.recv(100) == b"$PARVA\r\n"
    port.close()
    try:
        socket.create_connection((host, int(number)), timeout=2).close()
    except ConnectionRefusedError:
        pass
    else:
        raise AssertionError("the port still listens after close()")


def test_data_0xff_is_escaped_on_the_wire_and_unescaped_by_pyserials_client():
    data = b"$\xff\x00\xff\xffA\r\n"
    port = ServerPort("arva", parse_server_spec("rfc2217-server:127.0.0.1:0"))
    try:
        host, number = port.path.removeprefix("rfc2217://").rsplit(":", 1)
        with socket.create_connection((host, int(number)), timeout=5) as raw:
            _wait(lambda: port.clients == 1)
            port.write(data)
            raw.settimeout(5)
            got = b""
            while not got.endswith(b"\r\n"):
                chunk = raw.recv(4096)
                assert chunk, got
                got += chunk
            # The server's option requests come first, then the data, every 0xFF doubled.
            assert got.endswith(b"$\xff\xff\x00\xff\xff\xff\xffA\r\n")
        _wait(lambda: port.clients == 0)
        client = serial.serial_for_url(port.path, timeout=5)
        try:
            _wait(lambda: port.clients == 1)
            port.write(data)
            assert client.read(len(data)) == data
        finally:
            client.close()
    finally:
        port.close()
