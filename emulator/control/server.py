"""The control channel's socket server (BRIEF 9): JSON lines over a unix or TCP socket.

Addresses: ``unix:PATH`` (the socket is created with mode 0600, owner only; a stale
socket file left by a killed run is replaced, anything else at PATH is an error) or
``tcp:HOST:PORT`` (HOST must be a loopback address, 127.0.0.1, ::1 or a name resolving
only to loopback, unless ``any_host``; PORT 0 picks a free port, and the address
announced says which).

One thread serves every client with a selector. Several clients may be connected at
once (up to :data:`MAX_CLIENTS`); each gets exactly one reply per request, in order, on
its own connection, and sees the changes made by the others (they change one emulator).
Requests are executed one at a time in arrival order, except a long one (a ``step``):
the handler returns it as a :class:`Sliced` request, which the thread runs a slice at a
time (a ``step``: at most :data:`~emulator.control.controller.STEP_SLICE` epochs), serving
the other clients' requests between two slices; its reply is sent once its last slice is
done. Meanwhile its own client's further requests wait (unread: its socket applies back
pressure), and other clients' long requests queue behind it. When the server closes (a
``quit``, SIGTERM) a long request stops after its current slice and its client gets an
error reply saying how far it got. A line longer than
:data:`~emulator.control.requests.MAX_LINE`, bytes that are not UTF-8 or JSON, an
unknown op or an invalid value each get an error reply and change nothing; blank lines
are ignored. A client that does not read its replies is disconnected once
:data:`MAX_OUTBOX` bytes wait for it, so no client can stall the emulator.
"""

from __future__ import annotations

import errno
import ipaddress
import logging
import os
import selectors
import socket
import stat
import threading
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

from firmware_proto.errors import InputError, LinkError

from emulator.control.requests import MAX_LINE, ControlError, Quit, Request, encode_reply, error_reply, parse_request

log = logging.getLogger("arva-emulate")

MAX_CLIENTS = 64
#: Reply bytes that may wait for a client before it is disconnected.
MAX_OUTBOX = 1 << 20


@runtime_checkable
class Sliced(Protocol):
    """A long request, executed a slice at a time by the server's thread."""

    def advance(self) -> dict | None:
        """Do one slice: the reply once the request is complete, else None. May raise
        what a handler raises (an error reply)."""

    def abandon(self, why: str) -> dict:
        """The error reply of a request stopped before its end (``why``: the reason)."""


@dataclass(frozen=True)
class ControlAddress:
    """``unix:PATH`` or ``tcp:HOST:PORT``, parsed."""

    kind: str  # "unix" or "tcp"
    path: str = ""
    host: str = ""
    port: int = 0

    def __str__(self) -> str:
        if self.kind == "unix":
            return f"unix:{self.path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp:{host}:{self.port}"


def control_address(text: str) -> ControlAddress:
    """Parse ``unix:PATH`` / ``tcp:HOST:PORT``; :class:`InputError` names what is wrong
    (also an argparse type: ValueError subclasses become a usage error)."""
    kind, sep, rest = text.partition(":")
    if kind == "unix" and sep and rest:
        if len(os.fsencode(rest)) > 107:
            raise InputError(f"{text}: a unix socket path must be at most 107 bytes")
        return ControlAddress("unix", path=rest)
    if kind == "tcp" and sep:
        host, sep2, port = rest.rpartition(":")
        if host.startswith("[") and host.endswith("]"):
            host = host[1:-1]
        if sep2 and host and port.isdigit() and int(port) <= 65535:
            return ControlAddress("tcp", host=host, port=int(port))
    raise InputError(f"{text!r}: expected unix:PATH or tcp:HOST:PORT (e.g. tcp:127.0.0.1:7000)")


def is_loopback(host: str) -> bool:
    """True if every address ``host`` resolves to is a loopback address."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(i[4][0].split("%")[0]).is_loopback for i in infos)


def check_host(address: ControlAddress, any_host: bool) -> None:
    """InputError unless ``address`` is unix, loopback TCP, or ``any_host`` allows any."""
    if address.kind == "tcp" and not any_host and not is_loopback(address.host):
        raise InputError(
            f"--control {address}: {address.host} is not a loopback address "
            "(the channel has no authentication; add --control-any-host to serve other hosts)"
        )


class _Client:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.discarding = False  # inside an over-long line: drop bytes up to its newline
        self.quit_after_flush = False
        self.job: Sliced | None = None  # its long request being served (its other lines wait)
        self.events = 0  # the selector events it is registered for (0: not registered)


class ControlServer:
    """Serves ``handle(request) -> reply dict`` on ``address`` (see the module docstring).

    ``handle`` returns the reply, or a :class:`Sliced` request to run a slice at a time.
    ``on_quit`` is called once a ``quit`` reply has been sent (or its client has gone).
    """

    def __init__(
        self,
        address: ControlAddress,
        handle: Callable[[Request], dict | Sliced],
        on_quit: Callable[[], None],
        any_host: bool = False,
    ) -> None:
        self.address = address
        self.handle = handle
        self.on_quit = on_quit
        self.any_host = any_host
        self._sel = selectors.DefaultSelector()
        self._listener: socket.socket | None = None
        self._clients: dict[int, _Client] = {}
        self._wake_r, self._wake_w = os.pipe()
        self._closing = False
        self._thread: threading.Thread | None = None
        self._jobs: deque[_Client] = deque()  # clients whose long request runs (the first) or waits
        self._ready: deque[_Client] = deque()  # clients with request lines waiting to be served
        self.requests = 0
        self.errors = 0

    # --- lifecycle ----------------------------------------------------------------------

    def start(self) -> ControlAddress:
        """Bind and listen (raises :class:`InputError` / :class:`LinkError`), start the
        serving thread; return the address as bound (the real port for ``tcp:...:0``)."""
        a = self.address
        if a.kind == "unix":
            sock = self._bind_unix(a.path)
            bound = a
        else:
            check_host(a, self.any_host)
            try:
                infos = socket.getaddrinfo(a.host, a.port, type=socket.SOCK_STREAM)
            except OSError as exc:
                raise InputError(f"--control {a}: cannot resolve {a.host}: {exc.strerror or exc}") from None
            family, _, _, _, sockaddr = infos[0]
            sock = socket.socket(family, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind(sockaddr)
            except OSError as exc:
                sock.close()
                raise LinkError(f"--control {a}: cannot listen: {exc.strerror or exc}") from None
            bound = ControlAddress("tcp", host=a.host, port=sock.getsockname()[1])
        sock.listen(16)
        sock.setblocking(False)
        self._listener = sock
        self.bound = bound
        self._sel.register(sock, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._thread = threading.Thread(target=self._serve, name="arva-control", daemon=True)
        self._thread.start()
        return bound

    def _bind_unix(self, path: str) -> socket.socket:
        p = Path(path)
        try:
            st = p.lstat()
        except FileNotFoundError:
            st = None
        except OSError as exc:
            raise LinkError(f"--control unix:{path}: {exc.strerror}") from None
        if st is not None:
            if not stat.S_ISSOCK(st.st_mode):
                raise InputError(f"--control unix:{path}: exists and is not a socket (refusing to replace it)")
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                probe.connect(path)
            except OSError:
                p.unlink()  # stale: nobody listens
            else:
                raise LinkError(f"--control unix:{path}: another program is serving this socket")
            finally:
                probe.close()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # created 0600: no window in which others could connect
        try:
            sock.bind(path)
        except OSError as exc:
            sock.close()
            raise LinkError(f"--control unix:{path}: cannot listen: {exc.strerror or exc}") from None
        finally:
            os.umask(old)
        os.chmod(path, 0o600)
        return sock

    def close(self) -> None:
        """Stop serving, close every connection, remove the unix socket file."""
        if self._closing:
            return
        self._closing = True
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        for c in list(self._clients.values()):
            self._drop(c)
        if self._listener is not None:
            self._listener.close()
            if self.address.kind == "unix":
                try:
                    os.unlink(self.address.path)
                except OSError:
                    pass
        self._sel.close()
        os.close(self._wake_r)
        os.close(self._wake_w)

    # --- serving ------------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._closing:
            try:
                events = self._sel.select(timeout=0 if self._jobs or self._ready else 1.0)
            except OSError:
                break
            if any(key.data == "wake" for key, _ in events):
                break
            for key, mask in events:
                if key.data is None:
                    self._accept()
                    continue
                client: _Client = key.data
                if mask & selectors.EVENT_READ:
                    self._read(client)
                if mask & selectors.EVENT_WRITE and client.sock.fileno() >= 0:
                    self._flush(client)
            while self._ready:
                self._serve_inbox(self._ready.popleft())
            if self._jobs and not self._closing:
                self._advance()
        self._abandon_jobs("the emulator is stopping")

    def _advance(self) -> None:
        """One slice of the first long request; its reply when it is complete."""
        client = self._jobs[0]
        reply = self._execute(client.job.advance, client.job)
        if reply is None:
            return
        self._jobs.popleft()
        client.job = None
        self._reply(client, reply)
        if client.sock.fileno() >= 0:
            self._ready.append(client)  # its lines that waited, then its socket again

    def _abandon_jobs(self, why: str) -> None:
        """Error replies for the long requests still running or waiting (best effort:
        nothing blocks, the server is closing)."""
        while self._jobs:
            client = self._jobs.popleft()
            reply = client.job.abandon(why)
            client.job = None
            self.errors += 1
            client.outbox += encode_reply(reply)
            if client.sock.fileno() >= 0:
                try:
                    n = client.sock.send(client.outbox)
                    del client.outbox[:n]
                except OSError:
                    pass

    def _accept(self) -> None:
        try:
            sock, _ = self._listener.accept()
        except OSError:
            return
        if len(self._clients) >= MAX_CLIENTS:
            try:
                sock.send(encode_reply(error_reply(f"too many control clients (at most {MAX_CLIENTS})")))
            except OSError:
                pass
            sock.close()
            return
        sock.setblocking(False)
        client = _Client(sock)
        self._clients[sock.fileno()] = client
        self._watch(client)

    def _watch(self, client: _Client) -> None:
        """Register the client for what it needs: reading (unless its long request runs:
        its next lines wait in the socket), writing (while replies wait)."""
        events = (0 if client.job is not None else selectors.EVENT_READ) | (selectors.EVENT_WRITE if client.outbox else 0)
        if events == client.events or client.sock.fileno() < 0:
            return
        try:
            if client.events == 0:
                self._sel.register(client.sock, events, client)
            elif events == 0:
                self._sel.unregister(client.sock)
            else:
                self._sel.modify(client.sock, events, client)
        except (KeyError, ValueError, OSError):
            return
        client.events = events

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client)
            return
        client.inbox += data
        self._serve_inbox(client)

    def _serve_inbox(self, client: _Client) -> None:
        """Serve the client's complete lines in order, until one is a long request."""
        while client.job is None and client.sock.fileno() >= 0 and not client.quit_after_flush:
            nl = client.inbox.find(b"\n")
            if nl < 0:
                if len(client.inbox) > MAX_LINE and not client.discarding:
                    client.discarding = True
                    self._reply(client, error_reply(f"request longer than {MAX_LINE} bytes"))
                if client.discarding:
                    client.inbox.clear()
                break
            line = bytes(client.inbox[:nl])
            del client.inbox[: nl + 1]
            if client.discarding:
                client.discarding = False  # the tail of the over-long line: already answered
                continue
            self._serve_line(client, line)
        self._watch(client)

    def _execute(self, work: Callable[[], dict | Sliced | None], request: object) -> dict | Sliced | None:
        """``work()`` (the handler, or a slice of a long request), its errors as error replies."""
        try:
            return work()
        except ControlError as exc:
            return error_reply(str(exc))
        except InputError as exc:  # a value the model or a config rejected
            return error_reply(f"{getattr(request, 'op', 'request')}: {exc}")
        except Exception as exc:  # noqa: BLE001 - the emulator never dies of a request
            log.error("control: request %r failed:\n%s", request, traceback.format_exc())
            return error_reply(f"internal error: {type(exc).__name__}: {exc}")

    def _serve_line(self, client: _Client, line: bytes) -> None:
        if not line.strip():
            return
        self.requests += 1
        request = self._execute(lambda: parse_request(line), line[:200])
        if isinstance(request, dict):  # not a request: its error reply
            self._reply(client, request)
            return
        reply = self._execute(lambda: self.handle(request), request)
        if isinstance(reply, Sliced):
            client.job = reply  # run by the serving loop, a slice at a time
            self._jobs.append(client)
            return
        self._reply(client, reply)
        if isinstance(request, Quit) and reply.get("ok"):
            client.quit_after_flush = True
            self._flush(client, block=True)
            self.on_quit()

    def _reply(self, client: _Client, reply: dict) -> None:
        if not reply.get("ok"):
            self.errors += 1
        try:
            line = encode_reply(reply)
        except ValueError as exc:  # a NaN slipped into a reply: say so rather than die
            line = encode_reply(error_reply(f"internal error: reply not JSON: {exc}"))
        client.outbox += line
        self._flush(client)

    def _flush(self, client: _Client, block: bool = False) -> None:
        if client.sock.fileno() < 0:
            return
        if block:
            client.sock.settimeout(2.0)
        try:
            while client.outbox:
                n = client.sock.send(client.outbox)
                del client.outbox[:n]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EWOULDBLOCK):
                self._drop(client)
                return
        if block:
            return
        if len(client.outbox) > MAX_OUTBOX:
            log.warning("control: a client does not read its replies; disconnected")
            self._drop(client)
            return
        self._watch(client)

    def _drop(self, client: _Client) -> None:
        fd = client.sock.fileno()
        if fd >= 0:
            if client.events:
                try:
                    self._sel.unregister(client.sock)
                except (KeyError, ValueError, OSError):
                    pass
                client.events = 0
            self._clients.pop(fd, None)
        client.sock.close()
