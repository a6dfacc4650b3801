"""The control server in process (emulator/control/server.py on asyncio streams), with a
handler of our own: the client cap, line framing at MAX_LINE, the outbox cap, a slice
that blocks (a port write waiting for a slow reader) while the event loop keeps
answering, requests served between slices, close abandoning running and queued long
requests, and quit. Every read has a timeout."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from emulator.control.requests import MAX_LINE, Step, error_reply
from emulator.control.server import MAX_CLIENTS, ControlServer, control_address


class Job:
    """A long request of ``n`` slices; each slice waits for ``gate`` (a slow reader)
    under the emulator's lock, as a step's slice holds the scheduler's."""

    def __init__(self, n: int, gate: threading.Event, calls: list, lock: threading.Lock) -> None:
        self.n, self.done, self.gate, self.calls, self.lock = n, 0, gate, calls, lock

    def advance(self) -> dict | None:
        with self.lock:
            assert self.gate.wait(10)
            self.done += 1
            self.calls.append(f"slice {self.done}/{self.n}")
            return {"ok": True, "done": self.done} if self.done == self.n else None

    def abandon(self, why: str) -> dict:
        return error_reply(f"step: {why}: stopped after {self.done} of {self.n} epochs")


class Server:
    def __init__(self, path: str, big: int = 0) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self.calls: list[str] = []
        self.quitted = threading.Event()
        self.lock = threading.Lock()  # the emulator's (the Controller's scheduler lock)
        self.big = big
        self.server = ControlServer(control_address(f"unix:{path}"), self.handle, self.quitted.set)
        self.path = path
        self.server.start()

    def handle(self, req):
        if isinstance(req, Step):
            return Job(req.n, self.gate, self.calls, self.lock)
        with self.lock:
            self.calls.append(req.op)
        return {"ok": True, "op": req.op, **({"pad": "x" * self.big} if req.op == "truth" else {})}

    def connect(self) -> Client:
        return Client(self.path)


class Client:
    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX)
        self.sock.connect(path)  # blocking: a full backlog waits (a timeout would make it EAGAIN)
        self.sock.settimeout(10)
        self.buf = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def reply(self, timeout: float = 10.0) -> dict:
        self.sock.settimeout(timeout)
        while b"\n" not in self.buf:
            chunk = self.sock.recv(65536)
            assert chunk, f"closed after {self.buf[:100]!r}"
            self.buf += chunk
        line, _, self.buf = self.buf.partition(b"\n")
        return json.loads(line)

    def eof(self, timeout: float = 10.0) -> bool:
        self.sock.settimeout(timeout)
        try:
            return self.sock.recv(1) == b""
        except ConnectionResetError:
            return True


@pytest.fixture
def srv(tmp_path):
    s = Server(str(tmp_path / "c.sock"))
    yield s
    s.gate.set()
    s.server.close()


def test_the_client_cap_is_an_error_reply_then_eof(srv):
    clients = [srv.connect() for _ in range(MAX_CLIENTS)]
    for c in clients:  # every one accepted and served
        c.send(b'{"op": "status"}\n')
        assert c.reply() == {"ok": True, "op": "status"}
    extra = srv.connect()
    assert extra.reply() == {"ok": False, "error": f"too many control clients (at most {MAX_CLIENTS})"}
    assert extra.eof()
    clients.pop().sock.close()
    time.sleep(0.2)  # the server sees it go
    again = srv.connect()
    again.send(b'{"op": "status"}\n')
    assert again.reply() == {"ok": True, "op": "status"}


def test_lines_up_to_max_line_are_served_a_longer_one_is_answered_before_its_newline(srv):
    c = srv.connect()
    request = b'{"op": "status"}'
    c.send(b" " * (MAX_LINE - len(request)) + request + b"\n")  # exactly MAX_LINE bytes
    assert c.reply() == {"ok": True, "op": "status"}
    c.send(b" " * MAX_LINE + request + b"\n")  # one line, newline included in the same send
    assert c.reply() == {"ok": False, "error": f"request longer than {MAX_LINE} bytes"}
    c.send(b"{" * (3 * MAX_LINE))  # no newline yet: answered all the same
    assert c.reply() == {"ok": False, "error": f"request longer than {MAX_LINE} bytes"}
    c.send(b"{" * 1000 + b'\n\n\xff\xfe\n{"op": "truth"}\n')  # its tail, a blank line, not UTF-8, a request
    assert c.reply() == {"ok": False, "error": "request is not UTF-8 (byte offset 0)"}
    assert c.reply() == {"ok": True, "op": "truth", "pad": ""}
    assert srv.calls == ["status", "truth"]


def test_a_client_that_does_not_read_its_replies_is_dropped_others_are_served(tmp_path, caplog):
    s = Server(str(tmp_path / "c.sock"), big=100_000)
    try:
        lazy = s.connect()
        lazy.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        lazy.send(b'{"op": "truth"}\n' * 100)  # 10 MB of replies, never read
        other = s.connect()
        deadline = time.monotonic() + 10
        while "control: a client does not read its replies; disconnected" not in caplog.text:
            other.send(b'{"op": "status"}\n')
            assert other.reply(timeout=2) == {"ok": True, "op": "status"}
            assert time.monotonic() < deadline
            time.sleep(0.05)
        got = 0
        lazy.sock.settimeout(10)
        try:
            while chunk := lazy.sock.recv(1 << 20):
                got += len(chunk)
        except ConnectionResetError:
            pass
        assert got < 3_000_000  # what the socket buffers held, not the 10 MB asked
    finally:
        s.server.close()


def test_a_blocked_slice_does_not_stop_the_loop_and_others_go_between_slices(srv):
    srv.gate.clear()  # the first slice waits (a port write to a slow reader)
    a, b = srv.connect(), srv.connect()
    a.send(b'{"op": "step", "n": 3}\n{"op": "truth"}\n')
    time.sleep(0.2)
    t0 = time.monotonic()
    b.send(b'nonsense\n{"op": "status"}\n')
    assert b.reply(timeout=2)["error"].startswith("request is not JSON")
    assert time.monotonic() - t0 < 1.0  # answered by the loop while the slice waits
    time.sleep(0.2)
    assert srv.calls == []
    srv.gate.set()
    assert b.reply() == {"ok": True, "op": "status"}
    assert a.reply() == {"ok": True, "done": 3}
    assert a.reply()["op"] == "truth"  # a's next line waited for its step
    assert srv.calls == ["slice 1/3", "status", "slice 2/3", "slice 3/3", "truth"]


def test_close_abandons_the_running_step_after_its_slice_and_the_queued_one(srv, tmp_path):
    srv.gate.clear()
    a, b = srv.connect(), srv.connect()
    a.send(b'{"op": "step", "n": 5}\n')
    time.sleep(0.2)
    b.send(b'{"op": "step", "n": 2}\n')  # queues behind a's
    time.sleep(0.2)
    threading.Timer(0.3, srv.gate.set).start()
    t0 = time.monotonic()
    srv.server.close()  # returns once a's current slice is done
    assert 0.2 < time.monotonic() - t0 < 3.0
    assert a.reply() == {"ok": False, "error": "step: the emulator is stopping: stopped after 1 of 5 epochs"}
    assert b.reply() == {"ok": False, "error": "step: the emulator is stopping: stopped after 0 of 2 epochs"}
    assert a.eof() and b.eof()
    assert not (tmp_path / "c.sock").exists()


def test_quit_replies_then_calls_on_quit_and_serves_that_client_no_more(srv):
    c = srv.connect()
    c.send(b'{"op": "quit"}\n{"op": "status"}\n')
    assert c.reply() == {"ok": True, "op": "quit"}
    assert srv.quitted.wait(5)
    assert c.eof()
    assert srv.calls == ["quit"]


def test_a_stale_socket_is_replaced_and_a_live_one_refused(tmp_path):
    path = tmp_path / "c.sock"
    stale = socket.socket(socket.AF_UNIX)
    stale.bind(str(path))
    stale.close()
    first = Server(str(path))
    try:
        with pytest.raises(Exception, match=f"--control unix:{path}: another program is serving this socket"):
            Server(str(path))
        c = first.connect()
        c.send(b'{"op": "status"}\n')
        assert c.reply() == {"ok": True, "op": "status"}
    finally:
        first.server.close()


@pytest.mark.subprocess
@pytest.mark.slow
def test_a_slice_that_never_ends_does_not_hold_up_the_exit(tmp_path):
    """close() gives up on a stuck slice after CLOSE_WAIT_S and the process exits: the
    slice's worker is a daemon thread (an executor's would be joined at exit)."""
    import subprocess
    import sys

    script = f"""
import socket, threading, time
from emulator.control.server import ControlServer, control_address
from emulator.control.requests import Step

class Stuck:
    def advance(self):
        threading.Event().wait()  # a port write that never returns
    def abandon(self, why):
        return {{"ok": False, "error": why}}

server = ControlServer(control_address("unix:{tmp_path}/c.sock"), lambda req: Stuck(), lambda: None)
server.start()
c = socket.socket(socket.AF_UNIX)
c.connect("{tmp_path}/c.sock")
c.sendall(b'{{"op": "step", "n": 5}}\\n')
time.sleep(0.5)
server.close()
print("closed", flush=True)
"""
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    assert (r.returncode, r.stdout) == (0, "closed\n"), r.stderr
    assert time.monotonic() - t0 < 10.0
