"""rfc2217-server / tcp-server ports: a stream served to network clients, as a lab's
serial server would (pyserial's rfc2217:// client, a plain socket), with the client's
line settings honoured by an emulated UART."""

from __future__ import annotations

import functools
import select
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.session import SessionWriter
from emulator.output.net_ports import (
    UART_FIFO_BYTES,
    LineSettings,
    ServedClient,
    ServerPort,
    UartLine,
    is_ephemeral,
    parse_server_spec,
)
from firmware_proto.errors import InputError

EMULATE = [sys.executable, "-m", "emulator.cli"]


def start(cmd: list[str], announcements: int = 1, timeout: float = 20.0):
    """Start ``cmd``; return it and ``{label: url}`` from its announcement lines."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
    urls = {}
    deadline = time.monotonic() + timeout
    while len(urls) < announcements:
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            proc.kill()
            raise TimeoutError(f"no announcement: {proc.stderr.read()!r}")
        label, url = proc.stdout.readline().decode().split()
        urls[label] = url
    return proc, urls


def read_exactly(read, n: int, timeout: float = 20.0) -> bytes:
    """``n`` bytes from ``read(k)`` (which itself times out), or fail after ``timeout``."""
    got = b""
    deadline = time.monotonic() + timeout
    while len(got) < n:
        assert time.monotonic() < deadline, f"got {len(got)} of {n} bytes"
        got += read(n - len(got))
    return got


@functools.cache
def reference(*args: str) -> bytes:
    """What ``--port -`` prints for the same scene and frames (run once per argument list)."""
    proc = subprocess.run([*EMULATE, "--port", "-", "--speed", "0", *args], capture_output=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def serve(kind: str, frames: int, speed: str = "0", delay: str = "5") -> tuple[bytes, subprocess.Popen, str]:
    """The default scene's first ``frames`` epochs as ``--port -`` prints them, an emulator
    serving them on a ``kind`` (rfc2217-server, tcp-server) port of 127.0.0.1 after
    ``delay`` seconds (for the clients to connect), and the URL it announced."""
    expected = reference("--frames", str(frames))
    proc, urls = start([*EMULATE, "--port", f"{kind}:127.0.0.1:0", "--frames", str(frames), "--speed", speed,
                        "--delay", delay])
    return expected, proc, urls["arva"]


def host_port(url: str) -> tuple[str, int]:
    """(host, port) of a ``socket://`` or ``rfc2217://`` URL."""
    host, port = url.split("://", 1)[1].rsplit(":", 1)
    return host, int(port)


def finish(proc, timeout: float = 20.0) -> str:
    assert proc.wait(timeout=timeout) == 0, proc.stderr.read()
    return proc.stderr.read().decode()


# --- spec parsing and the UART model -------------------------------------------------


def test_parse_server_spec():
    assert parse_server_spec("rfc2217-server:127.0.0.1:4000").port == 4000
    assert parse_server_spec("tcp-server:[::1]:0").host == "::1"
    assert parse_server_spec("/dev/ttyUSB0") is None
    assert parse_server_spec("rfc2217://127.0.0.1:4000") is None  # a client URL
    assert is_ephemeral("tcp-server:localhost:0") and not is_ephemeral("tcp-server:localhost:1")
    with pytest.raises(InputError, match=r"^port tcp-server:127.0.0.1:x: expected a TCP port number 0..65535, got 'x'$"):
        parse_server_spec("tcp-server:127.0.0.1:x")
    with pytest.raises(InputError, match=r"^port rfc2217-server:4000: expected rfc2217-server:HOST:PORT"):
        parse_server_spec("rfc2217-server:4000")


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(["rfc2217-server", "tcp-server"]),
       st.sampled_from(["127.0.0.1", "localhost", "[::1]", "0.0.0.0", "lab-host.example"]),
       st.integers(0, 65535))
def test_server_specs_round_trip(kind, host, port):
    spec = parse_server_spec(f"{kind}:{host}:{port}")
    assert (spec.kind, spec.host, spec.port) == (kind, host.strip("[]"), port)
    assert is_ephemeral(f"{kind}:{host}:{port}") == (port == 0)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=40))
def test_any_port_text_parses_or_fails_with_one_input_error(text):
    """Never another exception: a spec is None (not a server port), a ServerSpec, or an
    InputError naming the text."""
    for candidate in (text, f"tcp-server:{text}", f"rfc2217-server:127.0.0.1:{text}"):
        try:
            spec = parse_server_spec(candidate)
        except InputError as exc:
            assert str(exc).startswith(f"port {candidate}: ")
            continue
        assert spec is None or 0 <= spec.port <= 65535


def test_line_settings():
    assert LineSettings().bits_per_char == 10
    assert LineSettings(9600, 7, "E", 2).bits_per_char == 11
    assert LineSettings(9600, 8, "N", 1.5).describe() == "9600 8N1.5"
    assert LineSettings(1200).bytes_per_s == 120.0


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_uart_line_drains_at_the_baud_rate():
    clock = FakeClock()
    line = UartLine(LineSettings(9600), fifo=1000, clock=clock)  # 960 bytes/s
    assert line.offer(1500) == 1000  # the FIFO, no more
    assert line.offer(1) == 0
    clock.t = 0.5
    assert line.room() == 480
    assert line.time_for(960) == pytest.approx(0.5)
    line.set_settings(LineSettings(1200))  # 120 bytes/s from now on
    clock.t = 1.5
    assert line.offer(10_000) == 480 + 120
    line.purge()
    assert line.room() == 1000


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 2), st.integers(0, 3000)), max_size=30), st.sampled_from([300, 9600, 115200]))
def test_uart_line_never_carries_more_than_fifo_plus_rate(steps, baud):
    """Whatever the write pattern, bytes carried <= FIFO + rate x elapsed time."""
    clock = FakeClock()
    line = UartLine(LineSettings(baud), clock=clock)
    carried = 0
    for dt, n in steps:
        clock.t += dt
        got = line.offer(n)
        assert 0 <= got <= n
        carried += got
        assert carried <= UART_FIFO_BYTES + clock.t * baud / 10 + 1e-6


@pytest.mark.subprocess
def test_loopback_only_unless_allowed():
    proc = subprocess.run(
        [*EMULATE, "--port", "rfc2217-server:0.0.0.0:0", "--frames", "1", "--speed", "0"],
        capture_output=True, timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stdout == b""
    assert proc.stderr == (
        b"arva-emulate: port rfc2217-server:0.0.0.0:0: 0.0.0.0 is not a loopback address; "
        b"add --serve-any-host to serve other hosts\n"
    )
    port = ServerPort("arva", parse_server_spec("tcp-server:0.0.0.0:0"), serve_any_host=True)
    try:
        assert port.path.startswith("socket://0.0.0.0:")
    finally:
        port.close()


def test_a_host_that_does_not_resolve_is_named_as_such(monkeypatch):
    def refuse(*_args, **_kwargs):
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", refuse)
    with pytest.raises(InputError) as err:
        ServerPort("arva", parse_server_spec("tcp-server:nowhere.invalid:0"))
    assert str(err.value) == "port tcp-server:nowhere.invalid:0: cannot resolve 'nowhere.invalid': Name or service not known"


def test_a_name_idna_cannot_encode_is_one_input_error():
    with pytest.raises(InputError) as err:
        ServerPort("arva", parse_server_spec("tcp-server:a..b:0"), serve_any_host=True)
    assert str(err.value).startswith("port tcp-server:a..b:0: cannot resolve 'a..b': ")


def test_the_loopback_check_is_on_the_addresses_bound(monkeypatch):
    """One lookup: a name whose answer changes between a check and the bind (DNS rebinding)
    cannot put the unauthenticated server on another host."""
    answers = [("127.0.0.1", 0), ("0.0.0.0", 0)]
    real = socket.getaddrinfo

    def rebinding(host, port, *args, **kwargs):
        addr = answers.pop(0) if host == "rebind.test" else None
        return real(addr[0] if addr else host, port, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", rebinding)
    port = ServerPort("arva", parse_server_spec("tcp-server:rebind.test:0"))
    try:
        assert port.path.startswith("socket://127.0.0.1:") and answers == [("0.0.0.0", 0)]
    finally:
        port.close()
    with pytest.raises(InputError) as err:
        ServerPort("arva", parse_server_spec("tcp-server:rebind.test:0"))
    assert str(err.value) == (
        "port tcp-server:rebind.test:0: rebind.test is not a loopback address; add --serve-any-host to serve other hosts"
    )


# --- served emulator ------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_rfc2217_clients_read_exactly_the_stdout_sentences():
    expected, proc, url = serve("rfc2217-server", 10)
    assert url.startswith("rfc2217://127.0.0.1:")
    # Two clients at once, one at 9600 baud (1070 bytes fit its 4 KB FIFO): both get it all.
    with serial.serial_for_url(url, baudrate=9600, timeout=2) as a, \
            serial.serial_for_url(url, baudrate=115200, timeout=2) as b:
        # Read both as the data comes: pyserial's client refuses to read what it buffered
        # once the server has closed (the emulator does at its last frame).
        got = {a: b"", b: b""}
        deadline = time.monotonic() + 20
        while any(len(v) < len(expected) for v in got.values()):
            assert time.monotonic() < deadline, {k.port: len(v) for k, v in got.items()}
            for s in got:
                if len(got[s]) < len(expected):
                    got[s] += s.read(min(s.in_waiting, len(expected) - len(got[s])) or 1)
        assert got[a] == expected and got[b] == expected
    err = finish(proc)
    assert "client 127.0.0.1:" in err and "set line 9600 8N1" in err
    assert f"{len(expected)} bytes sent, 0 dropped (line 9600 8N1)" in err
    assert f"{len(expected)} bytes sent, 0 dropped (line 115200 8N1)" in err
    assert "10 epochs sent (arva 10), 0 bytes dropped" in err


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_a_baud_too_low_for_the_stream_drops_what_the_uart_cannot_carry():
    # As fast as possible, 100 epochs go out in one write: a 1200 baud line takes its
    # FIFO's worth at once and drops the rest, as a device's UART would.
    expected, proc, url = serve("rfc2217-server", 100)
    with serial.serial_for_url(url, baudrate=1200, timeout=2) as s:
        got = read_exactly(s.read, UART_FIFO_BYTES)
    assert got == expected[:UART_FIFO_BYTES]
    err = finish(proc)
    dropped = len(expected) - UART_FIFO_BYTES
    assert f"100 epochs sent (arva 100), {dropped} bytes dropped" in err
    assert f"{UART_FIFO_BYTES} bytes sent, {dropped} dropped (line 1200 8N1)" in err


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_client_changing_the_baud_mid_stream():
    # 20 epochs/s of ~107 bytes (about 2140 bytes/s): fine at 115200 baud, too much for
    # 1200 (120 bytes/s), where the UART's FIFO fills and then bytes drop.
    frames = 80
    expected, proc, url = serve("rfc2217-server", frames, speed="20")
    received = b""
    with serial.serial_for_url(url, baudrate=115200, timeout=1.0) as s:
        head = read_exactly(s.read, len(b"".join(expected.splitlines(keepends=True)[:8])))  # 2 epochs
        assert head == expected[: len(head)]
        s.baudrate = 1200
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # until the stream has ended (1 s of silence)
            chunk = s.read(4096)
            if not chunk:
                break
            received += chunk
    err = finish(proc)
    assert "set line 1200 8N1" in err
    line = next(x for x in err.splitlines() if "left:" in x)
    sent, dropped = (int(w) for w in line.split("left: ")[1].replace(" bytes sent,", "").split()[:2])
    assert sent == len(head) + len(received)
    assert sent + dropped == len(expected)
    # After the change the line carries at most its FIFO plus 120 bytes/s for the run's
    # remaining <= 4 s (80 epochs at 20x real time); the rest was dropped.
    assert dropped > len(expected) - len(head) - UART_FIFO_BYTES - 120 * 4 - 200
    assert f"{dropped} bytes dropped" in err
    # Until the FIFO first filled, nothing was lost: the bytes continue the stream exactly.
    assert len(received) > 3000
    assert received[:3000] == expected[len(head) : len(head) + 3000]


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_tcp_server_with_a_plain_socket():
    expected, proc, url = serve("tcp-server", 10)
    with socket.create_connection(host_port(url), timeout=5) as sock:
        sock.settimeout(15)  # longer than the emulator's --delay 5: the first bytes come after it
        got = read_exactly(sock.recv, len(expected))
        assert sock.recv(1) == b""  # the emulator closes the connection when it ends
    assert got == expected
    assert f"{len(expected)} bytes sent, 0 dropped (line 115200 8N1)" in finish(proc)


@pytest.mark.subprocess
def test_a_fixed_port_is_the_one_served_and_a_busy_one_is_an_error():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        free = probe.getsockname()[1]
    port = ServerPort("arva", parse_server_spec(f"tcp-server:127.0.0.1:{free}"))
    try:
        assert port.path == f"socket://127.0.0.1:{free}"
        proc = subprocess.run([*EMULATE, "--port", f"rfc2217-server:127.0.0.1:{free}", "--frames", "1"],
                              capture_output=True, timeout=60)
        assert proc.returncode == 2
        assert proc.stderr == (
            f"arva-emulate: port rfc2217-server:127.0.0.1:{free}: cannot listen: Address already in use\n".encode()
        )
    finally:
        port.close()


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_a_vanished_client_costs_nothing():
    expected, proc, url = serve("tcp-server", 40, speed="20", delay="3")
    sock = socket.create_connection(host_port(url), timeout=5)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()  # reset, gone before the first epoch
    err = finish(proc)  # the run ends on time (finish() waits 20 s at most)
    assert "left: 0 bytes sent, 0 dropped" in err
    # Nobody heard any epoch: every byte is counted dropped, none is queued anywhere.
    assert f"40 epochs sent (arva 40), {len(expected)} bytes dropped" in err


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_several_streams_each_get_their_own_free_port():
    scene = "emulator/scenes/field_walk.toml"
    proc, urls = start([*EMULATE, "--scene", scene, "--port", "tcp-server:127.0.0.1:0", "--frames", "1",
                        "--speed", "0"], announcements=3)
    assert sorted(urls) == ["arva", "attitude", "gps"]
    assert len(set(urls.values())) == 3
    assert "0 bytes written" not in finish(proc)
    # A fixed port cannot carry two streams.
    clash = subprocess.run([*EMULATE, "--scene", scene, "--port", "tcp-server:127.0.0.1:4999", "--frames", "1"],
                           capture_output=True, timeout=60)
    assert clash.returncode == 2
    assert clash.stderr == (b"arva-emulate: port tcp-server:127.0.0.1:4999: 3 streams (arva, gps, attitude) "
                            b"cannot share tcp-server:127.0.0.1:4999; use --port pty or --stream LABEL=PORT\n")


# --- served replay ---------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_replayed_session_served_over_rfc2217(tmp_path):
    expected = reference("--frames", "10")
    w = SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"}}})
    lines = expected.splitlines(keepends=True)
    for k, line in enumerate(lines):
        w.raw("arva", line, mono=100.0 + 0.01 * k, utc=0.0)
    w.close()
    proc, urls = start([sys.executable, "-m", "bench.cli", "replay", str(tmp_path / "s"),
                        "--port", "rfc2217-server:127.0.0.1:0", "--delay", "5", "--speed", "0"])
    with serial.serial_for_url(urls["arva"], baudrate=115200, timeout=2) as s:
        assert read_exactly(s.read, len(expected)) == expected
    err = finish(proc)
    assert f"arva-bench: replay: {len(lines)} reads, {len(expected)} bytes written, 0 bytes dropped\n" in err
    assert f"arva-bench: replay: arva: client 127.0.0.1:" in err


def test_a_malformed_rfc2217_request_disconnects_that_client_only():
    lines: list[str] = []
    port = ServerPort("arva", parse_server_spec("rfc2217-server:127.0.0.1:0"), notify=lines.append)
    try:
        with socket.create_connection(host_port(port.path), timeout=5) as sock:
            sock.settimeout(5)
            # IAC SB COM-PORT-OPTION SET-BAUDRATE with one byte instead of four, IAC SE
            sock.sendall(b"\xff\xfa\x2c\x01\x00\xff\xf0")
            deadline = time.monotonic() + 10
            while sock.recv(4096):  # the server's option requests, then EOF
                assert time.monotonic() < deadline
        deadline = time.monotonic() + 10
        while port.clients:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert port.write(b"$PARVA\r\n") == 0  # nobody connected now: dropped, counted
        assert port.bytes_dropped == 8
    finally:
        port.close()
    assert any("bad RFC 2217 request" in line and "disconnecting" in line for line in lines), lines
    assert lines[-1].endswith("left: 0 bytes sent, 0 dropped (line 115200 8N1)")


def test_a_baud_rate_out_of_limits_is_refused_like_a_real_port_server():
    lines: list[str] = []
    port = ServerPort("arva", parse_server_spec("rfc2217-server:127.0.0.1:0"), notify=lines.append)
    try:
        with serial.serial_for_url(port.path, baudrate=9600, timeout=1) as s:
            with pytest.raises(ValueError, match="remote rejected value for option 'baudrate'"):
                s.baudrate = 20_000_000  # above BAUD_LIMITS: answered with the current 9600
    finally:
        port.close()
    assert [line.split(" ", 3)[3] for line in lines] == [
        "connected (rfc2217-server, line 115200 8N1)",
        "set line 9600 8N1",
        "left: 0 bytes sent, 0 dropped (line 9600 8N1)",
    ]


# --- who sends: the emulator's own write, at the deadline --------------------------


class FakeSocket:
    """A client socket that records what is sent, from which thread and how.

    ``accept`` bounds what one non-blocking send() takes (0: a full socket); sendall()
    takes everything but first waits for ``sendall_go`` (set by default); recv() blocks
    until ``hang_up`` is set, then reports the client gone."""

    def __init__(self, accept: int = 1 << 20) -> None:
        self.accept = accept
        self.sent: list[tuple[str, int, bytes]] = []  # (how, thread id, bytes)
        self.sendall_go = threading.Event()
        self.sendall_go.set()
        self.in_sendall = threading.Event()
        self.hang_up = threading.Event()

    def send(self, data: bytes, flags: int = 0) -> int:
        assert flags & socket.MSG_DONTWAIT
        n = min(len(data), self.accept)
        if n == 0:
            raise BlockingIOError
        self.sent.append(("send", threading.get_ident(), bytes(data[:n])))
        return n

    def sendall(self, data: bytes) -> None:
        self.in_sendall.set()
        assert self.sendall_go.wait(10)
        self.sent.append(("sendall", threading.get_ident(), bytes(data)))

    def recv(self, _n: int) -> bytes:
        assert self.hang_up.wait(10)
        return b""

    def shutdown(self, _how) -> None:
        pass

    def close(self) -> None:
        pass

    def received(self) -> bytes:
        return b"".join(d for _how, _t, d in self.sent)


@pytest.fixture
def tcp_port():
    port = ServerPort("arva", parse_server_spec("tcp-server:127.0.0.1:0"))
    yield port
    port.close()


def _wait_for(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


def test_a_served_client_is_sent_the_epoch_from_the_writers_own_thread(tcp_port):
    sock = FakeSocket()
    client = ServedClient(tcp_port, sock, ("127.0.0.1", 1))  # threads not started: only offer() can send
    client.offer(b"$PARVA,0,4,1*00\r\n")
    client.offer(b"$PARVA,0,4,2*00\r\n")
    assert sock.sent == [("send", threading.get_ident(), b"$PARVA,0,4,1*00\r\n"),
                         ("send", threading.get_ident(), b"$PARVA,0,4,2*00\r\n")]
    assert client.bytes_sent == 34 and client.bytes_dropped == 0


def test_what_the_socket_cannot_take_at_once_follows_in_order_from_the_sender(tcp_port):
    sock = FakeSocket(accept=5)
    client = ServedClient(tcp_port, sock, ("127.0.0.1", 1))
    client.offer(b"0123456789")  # 5 bytes sent now, 5 queued
    client.offer(b"abcdef")  # something is queued: all of it waits behind it
    assert sock.sent == [("send", threading.get_ident(), b"01234")]
    client.start()
    _wait_for(lambda: len(sock.received()) == 16)
    assert sock.received() == b"0123456789abcdef"
    assert [how for how, _t, _d in sock.sent] == ["send", "sendall"]
    assert sock.sent[1][1] != threading.get_ident()
    sock.hang_up.set()
    client.close(time.monotonic() + 5)


def test_no_byte_overtakes_the_ones_the_sender_is_sending(tcp_port):
    sock = FakeSocket(accept=0)  # full: the first epoch goes to the sender
    sock.sendall_go.clear()
    client = ServedClient(tcp_port, sock, ("127.0.0.1", 1))
    client.start()
    client.offer(b"first")
    assert sock.in_sendall.wait(10)  # the sender holds "first", its queue is empty again
    sock.accept = 1 << 20  # the socket would take the next epoch now ...
    client.offer(b"second")  # ... but it must wait for "first"
    sock.sendall_go.set()
    _wait_for(lambda: len(sock.received()) == 11)
    assert sock.received() == b"firstsecond"
    assert [how for how, _t, _d in sock.sent] == ["sendall", "sendall"]
    sock.hang_up.set()
    client.close(time.monotonic() + 5)
