"""The control channel's socket server (BRIEF 9): JSON lines over a unix or TCP socket.

Addresses (docs/hil_testing.md, "The control channel"): ``unix:PATH`` (mode 0600, a
stale socket file replaced) or ``tcp:HOST:PORT`` (loopback only unless ``any_host``;
PORT 0 picks a free port, announced). An asyncio event loop in its own thread serves up
to :data:`MAX_CLIENTS` clients, one reply per request, in order ("Several clients").
Requests run one at a time in the loop's thread, except a long one (a ``step``), which
the handler returns as a :class:`Sliced` request: a worker thread runs it a slice at a
time while the loop serves the other clients; meanwhile its own client's further
requests wait unread (back pressure) and other long requests queue behind it. On close
it stops after its current slice and its client is told how far it got. The caps
(:data:`~emulator.control.requests.MAX_LINE`, :data:`MAX_OUTBOX`, :data:`MAX_CLIENTS`):
docs/reliability.md, "Bounded servers".
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import queue
import socket
import stat
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from firmware_proto.errors import InputError, LinkError

from emulator.output.net_ports import all_loopback, format_addr, resolve, tcp_listener

from emulator.control.requests import MAX_LINE, ControlError, Quit, Request, encode_reply, error_reply, parse_request

log = logging.getLogger("arva-emulate")

MAX_CLIENTS = 64
#: Reply bytes that may wait for a client before it is disconnected.
MAX_OUTBOX = 1 << 20
#: How long a ``quit`` reply may take to leave before the run ends anyway, seconds.
QUIT_FLUSH_S = 2.0
#: How long :meth:`ControlServer.close` waits for the requests being served (a ``step``:
#: its current slice) before it gives up on them, seconds.
CLOSE_WAIT_S = 5.0


@runtime_checkable
class Sliced(Protocol):
    """A long request, executed a slice at a time by the server's worker thread."""

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
        return f"unix:{self.path}" if self.kind == "unix" else f"tcp:{format_addr((self.host, self.port))}"


def control_address(text: str) -> ControlAddress:
    """Parse ``unix:PATH`` / ``tcp:HOST:PORT``; :class:`InputError` names what is wrong
    (``--control`` wraps it in :func:`runtime._address`: argparse would print its own
    "invalid value" line for a ValueError, not this message)."""
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


def check_host(address: ControlAddress, any_host: bool) -> None:
    """InputError unless ``address`` is unix, loopback TCP, or ``any_host`` allows any (the
    command line's early check; the listener checks again on the addresses it binds)."""
    where = f"--control {address}"
    if address.kind == "tcp" and not any_host and not all_loopback(resolve(address.host, None, where)):
        raise InputError(f"{where}: {_remote(address)}")


def _remote(address: ControlAddress) -> str:
    return (f"{address.host} is not a loopback address (the channel has no authentication; "
            "add --control-any-host to serve other hosts)")


class ControlServer:
    """Serves ``handle(request) -> reply dict`` on ``address`` (see the module docstring).

    ``handle`` returns the reply, or a :class:`Sliced` request to run a slice at a time;
    it is called in the server's thread, the slices in its worker thread, at the same
    time as ``handle`` may be: both guard the state they share with one lock (as
    :class:`~emulator.control.controller.Controller` does). ``on_quit`` is called
    (in the server's thread) once a ``quit`` reply has been sent, or its client has gone.
    """

    def __init__(self, address: ControlAddress, handle: Callable[[Request], dict | Sliced],
                 on_quit: Callable[[], None], any_host: bool = False) -> None:
        self.address = address
        self.handle = handle
        self.on_quit = on_quit
        self.any_host = any_host
        self._loop: asyncio.AbstractEventLoop | None = None
        self._slices: queue.SimpleQueue = queue.SimpleQueue()  # (future, long request) for the worker; None: stop
        self._stop = asyncio.Event()
        self._one_job = asyncio.Lock()  # long requests run one at a time, in arrival order
        self._clients: set[asyncio.Task] = set()
        self._reading: set[asyncio.Task] = set()  # clients waiting for their next line
        self._listener: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._closing = False  # set in the loop: the requests being served are the last

    # --- lifecycle ----------------------------------------------------------------------

    def start(self) -> ControlAddress:
        """Bind and listen (raises :class:`InputError` / :class:`LinkError`), start the
        serving thread; return the address as bound (the real port for ``tcp:...:0``)."""
        a = self.address
        if a.kind == "unix":
            sock = self._bind_unix(a.path)
            sock.listen(16)  # connections wait in the backlog until the loop runs
            bound = a
        else:
            remote = None if self.any_host else _remote(a)
            sock = tcp_listener(a.host, a.port, f"--control {a}", backlog=16, remote=remote)
            bound = ControlAddress("tcp", host=a.host, port=sock.getsockname()[1])
        self._listener = sock
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, args=(sock,), name="arva-control", daemon=True)
        self._thread.start()
        threading.Thread(target=self._work, name="arva-control-slices", daemon=True).start()
        return bound

    def _bind_unix(self, path: str) -> socket.socket:
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            st = None
        except OSError as exc:
            raise LinkError(f"--control unix:{path}: {exc.strerror}") from None
        if st is not None:
            if not stat.S_ISSOCK(st.st_mode):
                raise InputError(f"--control unix:{path}: exists and is not a socket (refusing to replace it)")
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
                try:
                    probe.connect(path)
                except OSError:
                    os.unlink(path)  # stale: nobody listens
                else:
                    raise LinkError(f"--control unix:{path}: another program is serving this socket")
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
        """Stop serving (a long request after its current slice, its client told how far
        it got), close every connection, remove the unix socket file."""
        if self._listener is None:
            return
        listener, self._listener = self._listener, None
        if self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
            if self._thread is not threading.current_thread():
                self._thread.join(timeout=CLOSE_WAIT_S + 1)
        listener.close()
        self._slices.put(None)
        if self.address.kind == "unix":
            with contextlib.suppress(OSError):
                os.unlink(self.address.path)

    # --- serving (in the server's thread) ------------------------------------------------

    def _run(self, sock: socket.socket) -> None:
        try:
            self._loop.run_until_complete(self._serve(sock))
        finally:
            self._loop.close()

    async def _serve(self, sock: socket.socket) -> None:
        server = await asyncio.start_server(self._client, sock=sock, limit=MAX_LINE)  # unix or TCP: bound above
        await self._stop.wait()
        self._closing = True
        server.close()
        for task in self._reading:
            task.cancel()
        if self._clients:  # the others finish the request they serve (a step: its slice)
            await asyncio.wait(self._clients, timeout=CLOSE_WAIT_S)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._closing:
            writer.transport.abort()
            return
        if len(self._clients) >= MAX_CLIENTS:
            writer.write(encode_reply(error_reply(f"too many control clients (at most {MAX_CLIENTS})")))
            writer.close()
            return
        task = asyncio.current_task()
        self._clients.add(task)
        try:
            while not self._closing and not writer.is_closing():
                self._reading.add(task)
                try:
                    line = await self._next_line(reader, writer)
                finally:
                    self._reading.discard(task)
                if not await self._serve_line(line, writer):
                    break
        except (asyncio.IncompleteReadError, ConnectionError):
            pass  # the client has gone
        finally:
            self._clients.discard(task)
            if self._closing:
                writer.transport.abort()  # its last reply went as far as the socket took it at once
            else:
                writer.close()

    async def _next_line(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> bytes:
        """The client's next request line (without its newline); an over-long line is
        answered as soon as it is seen, then skipped up to its newline; blank lines are
        skipped. IncompleteReadError once the client has gone."""
        while True:
            try:
                line = await reader.readuntil(b"\n")
            except asyncio.LimitOverrunError as exc:
                self._reply(writer, error_reply(f"request longer than {MAX_LINE} bytes"))
                while True:
                    await reader.readexactly(exc.consumed)
                    try:
                        await reader.readuntil(b"\n")
                        break
                    except asyncio.LimitOverrunError as more:
                        exc = more
                continue
            if line.strip():
                return line[:-1]

    async def _serve_line(self, line: bytes, writer: asyncio.StreamWriter) -> bool:
        """Serve one request and send its reply; False after a ``quit`` (the client is done)."""
        request = self._execute(lambda: parse_request(line), line[:200])
        if isinstance(request, dict):  # not a request: its error reply
            self._reply(writer, request)
            return True
        reply = self._execute(lambda: self.handle(request), request)
        if isinstance(reply, Sliced):
            reply = await self._run_sliced(reply)
        self._reply(writer, reply)
        if isinstance(request, Quit) and reply.get("ok"):
            writer.transport.set_write_buffer_limits(high=0)  # drain() now waits for every byte
            with contextlib.suppress(TimeoutError, ConnectionError):
                await asyncio.wait_for(writer.drain(), QUIT_FLUSH_S)
            self.on_quit()
            return False
        return True

    async def _run_sliced(self, job: Sliced) -> dict:
        """Run ``job`` a slice at a time (other clients' requests go between two slices)."""
        async with self._one_job:
            while not self._closing:
                # In the worker: while a slice waits for a slow reader (up to the port's
                # drain wait), the loop accepts and answers what needs no emulator.
                done = self._loop.create_future()
                self._slices.put((done, job))
                reply = await done
                if reply is not None:
                    return reply
            return job.abandon("the emulator is stopping")

    def _work(self) -> None:
        """The worker thread: one slice at a time. A daemon, as the server's thread is: a
        slice held by a slow reader does not hold up the end of the run."""
        while (item := self._slices.get()) is not None:
            done, job = item
            reply = self._execute(job.advance, job)
            try:
                self._loop.call_soon_threadsafe(_settle, done, reply)
            except RuntimeError:  # the loop has closed: nobody waits for this reply
                return

    def _execute(self, work: Callable[[], dict | Sliced | None], request: object) -> dict | Sliced | None:
        """``work()`` (the handler, or a slice of a long request), its errors as error replies."""
        try:
            return work()
        except InputError as exc:  # a ControlError: the reply's text; else named by the request's op
            op, text = getattr(request, "op", "request"), str(exc)
            named = isinstance(exc, ControlError) or text.startswith(f"{op}:")
            return error_reply(text if named else f"{op}: {text}")
        except Exception as exc:  # noqa: BLE001 - the emulator never dies of a request
            log.error("control: request %r failed:\n%s", request, traceback.format_exc())
            return error_reply(f"internal error: {type(exc).__name__}: {exc}")

    def _reply(self, writer: asyncio.StreamWriter, reply: dict) -> None:
        try:
            line = encode_reply(reply)
        except ValueError as exc:  # a NaN slipped into a reply: say so rather than die
            line = encode_reply(error_reply(f"internal error: reply not JSON: {exc}"))
        writer.write(line)
        if writer.transport.get_write_buffer_size() > MAX_OUTBOX:
            log.warning("control: a client does not read its replies; disconnected")
            writer.transport.abort()


def _settle(done: asyncio.Future, reply: dict | None) -> None:
    if not done.cancelled():
        done.set_result(reply)
