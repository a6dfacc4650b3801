"""Network ports: a stream served to TCP clients, as a lab's serial server would.

* ``rfc2217-server:HOST:PORT``: RFC 2217 (Telnet COM-PORT-OPTION), ser2net's and
  labgrid's protocol; the negotiation is pyserial's :class:`serial.rfc2217.PortManager`.
* ``tcp-server:HOST:PORT``: a raw socket (ser2net's raw mode; pyserial ``socket://``).

docs/emulator.md, "Network servers", is the user's view: port 0, loopback only unless
``--serve-any-host``, one emulated UART per client (its own line settings; ``baud /
bits_per_char`` bytes per second of wall-clock time out of a :data:`UART_FIFO_BYTES`
FIFO, the rest dropped and counted), the client events reported through ``notify``.
docs/reliability.md, "Bounded servers", lists the caps that keep a hostile client from
growing the emulator (:data:`MAX_SUBNEGOTIATION`, :data:`MAX_REPLIES_WAITING`,
:data:`SOCKET_BACKLOG_BYTES`, :data:`MAX_CLIENTS`, :data:`NOTIFY_SETTING_CHANGES`).

The emulator's :meth:`ServerPort.write` never waits for a socket: what a client's UART
accepted is sent from the caller's thread when the socket takes it at once, else queued
for that client's sender thread. :attr:`Port.bytes_written` sums the bytes the clients'
UARTs carried; :attr:`Port.bytes_dropped` what they dropped plus every byte written
while no client was connected.
"""

from __future__ import annotations

import contextlib
import ipaddress
import selectors
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import serial
import serial.rfc2217
from serial.serialutil import SerialBase

from firmware_proto.errors import InputError, LinkError

from emulator.cli_types import BAUD_LIMITS
from emulator.output.ports import Port
from emulator.output.virtual_line import VirtualLine

#: Transmit FIFO of every emulated UART, bytes (the Linux serial core's xmit buffer).
UART_FIFO_BYTES = 4096
#: Bytes a client's socket may have queued (accepted by its UART, not yet sent).
SOCKET_BACKLOG_BYTES = 256 * 1024
#: How long :meth:`ServerPort.close` waits for clients to take their last bytes and hang
#: up, seconds (all clients together). pyserial's rfc2217 client cannot read what it
#: buffered once the server has closed, so the server does not hang up first at once.
CLOSE_LINGER_S = 2.0
#: Port-spec prefixes handled here.
KINDS = ("rfc2217-server", "tcp-server")
#: Longest Telnet subnegotiation (bytes between ``IAC SB`` and ``IAC SE``) a client may
#: send; RFC 2217's longest useful one (a SIGNATURE text) is a few dozen bytes.
MAX_SUBNEGOTIATION = 4096
#: Telnet / RFC 2217 reply bytes that may wait for a client (queued because it does not
#: read them); beyond, the client is disconnected.
MAX_REPLIES_WAITING = 64 * 1024
#: Clients served at once by one port; a connection beyond is closed at once.
MAX_CLIENTS = 32
#: Refused connections reported one line each; the rest are only counted (reported at close).
NOTIFY_REFUSALS = 10
#: Line-setting changes of one client reported one line each; the rest are counted.
NOTIFY_SETTING_CHANGES = 20


@dataclass(frozen=True)
class ServerSpec:
    """A parsed ``KIND:HOST:PORT`` (``port`` 0: any free port; ``text`` as written)."""

    kind: str
    host: str
    port: int
    text: str


def parse_server_spec(text: str) -> ServerSpec | None:
    """``rfc2217-server:HOST:PORT`` or ``tcp-server:HOST:PORT`` (IPv6 as ``[::1]``);
    None if ``text`` is not a server spec; :class:`InputError` if it is one, malformed."""
    kind, sep, rest = text.partition(":")
    if not sep or kind not in KINDS:
        return None
    host, sep, port_text = rest.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host:
        raise InputError(f"port {text}: expected {kind}:HOST:PORT (e.g. {kind}:127.0.0.1:4000)")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise InputError(f"port {text}: expected a TCP port number 0..65535, got {port_text!r}")
    return ServerSpec(kind, host, port, text)


def is_ephemeral(text: str) -> bool:
    """True for a well-formed server spec on port 0 (each stream may have its own)."""
    try:
        spec = parse_server_spec(text)
    except InputError:
        return False
    return spec is not None and spec.port == 0


@dataclass(frozen=True)
class LineSettings:
    """UART framing: ``baudrate`` (bit/s), ``bytesize`` (5..8), ``parity`` (N E O M S),
    ``stopbits`` (1, 1.5, 2)."""

    baudrate: int = 115200
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1

    @property
    def bits_per_char(self) -> float:
        return 1 + self.bytesize + (0 if self.parity == "N" else 1) + self.stopbits

    @property
    def bytes_per_s(self) -> float:
        return self.baudrate / self.bits_per_char

    def describe(self) -> str:
        """``115200 8N1`` (``1.5`` stop bits as ``1.5``)."""
        return f"{self.baudrate} {self.bytesize}{self.parity}{self.stopbits:g}"


class UartLine:
    """The transmit side of one UART: a FIFO of ``fifo`` bytes drained at the line rate.

    ``offer(n)`` returns how many of ``n`` bytes fit now; ``room()`` / ``time_for(n)``
    let a caller wait for the line. Settings may change at any time (a client setting
    its baud rate): the FIFO level is brought up to date at the old rate first.
    ``clock`` is injectable for tests.
    """

    def __init__(self, settings: LineSettings, fifo: int = UART_FIFO_BYTES, clock=time.monotonic) -> None:
        self.fifo = fifo
        self.clock = clock
        self._lock = threading.Lock()
        self.settings = settings  # changed by set_settings
        self._level = 0.0
        self._t = clock()

    def _update(self) -> None:
        now = self.clock()
        self._level = max(0.0, self._level - (now - self._t) * self.settings.bytes_per_s)
        self._t = now

    def set_settings(self, settings: LineSettings) -> None:
        with self._lock:
            self._update()
            self.settings = settings

    def room(self) -> int:
        with self._lock:
            self._update()
            return int(self.fifo - self._level + 1e-9)

    def time_for(self, n: int) -> float:
        """Seconds until ``n`` bytes fit (0 if they fit now; never more than the FIFO)."""
        with self._lock:
            self._update()
            excess = self._level + min(n, self.fifo) - self.fifo
            return max(0.0, excess / self.settings.bytes_per_s)

    def offer(self, n: int) -> int:
        with self._lock:
            self._update()
            accepted = max(0, min(n, int(self.fifo - self._level + 1e-9)))
            self._level += accepted
            return accepted

    def purge(self) -> None:
        """Empty the FIFO (a client purging the server's receive buffer)."""
        with self._lock:
            self._update()
            self._level = 0.0


class _ClientUart(VirtualLine, SerialBase):
    """The serial-port object pyserial's PortManager configures for one client.

    Setting baud rate, data bits, parity or stop bits (an RFC 2217 SET_* request) goes
    through pyserial's own validation, then :data:`BAUD_LIMITS`; a refused value makes
    the PortManager restore and report the previous one, as a real port's server does.
    Modem lines read as a present device (:class:`VirtualLine`): CTS, DSR and CD on, RI off.
    """

    def __init__(self, settings: LineSettings, on_change: Callable[[LineSettings], None], on_purge) -> None:
        super().__init__(port=None, **asdict(settings))
        self._on_change = on_change
        self._on_purge = on_purge
        self.is_open = True  # from now on every setting change calls _reconfigure_port

    def _reconfigure_port(self) -> None:
        lo, hi = BAUD_LIMITS
        if not lo <= self._baudrate <= hi:
            raise ValueError(f"baud rate {self._baudrate} outside {lo}..{hi}")
        self._on_change(LineSettings(self._baudrate, self._bytesize, self._parity, self._stopbits))

    def reset_input_buffer(self) -> None:  # data from the device not yet sent to the client
        self._on_purge()


class ServedClient:
    """One connected client: its UART, its outgoing queue and a sender and reader thread."""

    def __init__(self, port: ServerPort, sock: socket.socket, addr) -> None:
        self.port = port
        self.sock = sock
        self.name = format_addr(addr)
        self.line = UartLine(port.settings)
        self.bytes_sent = 0
        self.bytes_dropped = 0
        self.setting_changes = 0  # line-setting changes (reported up to NOTIFY_SETTING_CHANGES)
        self.cut: str | None = None  # why the server disconnects it (a cap it exceeded)
        self.gone = threading.Event()
        self._control = bytearray()  # Telnet / RFC 2217 replies, sent first
        self._data = bytearray()  # stream bytes the UART carried, not yet sent
        self._cond = threading.Condition()
        self._closing = False
        self._sending = False  # the sender thread is writing bytes taken from the queues
        self.manager = None
        if port.spec.kind == "rfc2217-server":
            self.uart = _ClientUart(port.settings, self._settings_changed, self._purge)
            self.manager = serial.rfc2217.PortManager(self.uart, self)  # sends its option requests
        self._sender = threading.Thread(target=self._send_loop, name=f"{port.label} send {self.name}", daemon=True)
        self._reader = threading.Thread(target=self._read_loop, name=f"{port.label} read {self.name}", daemon=True)

    def start(self) -> None:
        self._sender.start()
        self._reader.start()

    # --- the PortManager's connection interface (Telnet replies), from the reader thread
    def write(self, data: bytes) -> None:
        with self._cond:
            if len(self._control) + len(data) > MAX_REPLIES_WAITING:
                # Dropped with the client (the reader disconnects it after this request).
                self.cut = self.cut or f"more than {MAX_REPLIES_WAITING} bytes of RFC 2217 replies wait unread"
                return
            self._control += data
            self._cond.notify()

    def _settings_changed(self, settings: LineSettings) -> None:
        if settings != self.line.settings:
            self.line.set_settings(settings)
            self.setting_changes += 1
            if self.setting_changes <= NOTIFY_SETTING_CHANGES:
                self.port.notify(f"{self.port.label}: client {self.name} set line {settings.describe()}")

    def _purge(self) -> None:
        self.line.purge()
        with self._cond:
            # Purged bytes never reach the client: count them dropped, not sent (each
            # data 0xFF is queued doubled by the Telnet escaping).
            n = len(self._data) - (self._data.count(0xFF) // 2 if self.manager is not None else 0)
            self.bytes_sent -= n
            self.bytes_dropped += n
            del self._data[:]

    # --- stream data, from the emulator's thread
    def offer(self, data: bytes) -> None:
        """Bytes the stream wrote: what the UART carries goes to the socket now, from the
        caller's thread, when nothing is queued before it and the socket takes it without
        blocking (the usual case); the rest is queued for the sender thread. Sending here
        delivers at the epoch's deadline: the kernel wakes the client from this write, and
        no other thread (at ordinary priority, behind the GIL) has to run first."""
        if self.gone.is_set():
            return
        n = self.line.offer(len(data))
        with self._cond:
            n = max(0, min(n, SOCKET_BACKLOG_BYTES - len(self._data)))
            chunk = data[:n]
            if self.manager is not None:
                chunk = escape_iac(chunk)
            self.bytes_sent += n
            self.bytes_dropped += len(data) - n
            if chunk and not (self._control or self._data or self._sending):
                # Full (BlockingIOError) or gone: the sender thread sends or finds out.
                with contextlib.suppress(OSError):
                    chunk = chunk[self.sock.send(chunk, socket.MSG_DONTWAIT) :]
            if chunk:
                self._data += chunk
                self._cond.notify()

    def _send_loop(self) -> None:
        try:
            while True:
                with self._cond:
                    while not (self._control or self._data) and not self._closing:
                        self._cond.wait()
                    if not (self._control or self._data):
                        break
                    data = bytes(self._control + self._data)
                    del self._control[:]
                    del self._data[:]
                    self._sending = True  # offer() must not send ahead of these bytes
                try:
                    self.sock.sendall(data)
                finally:
                    with self._cond:
                        self._sending = False
        except OSError:
            self._vanish()  # the client is gone (reset, broken pipe)

    def _read_loop(self) -> None:
        try:
            while not self.gone.is_set():
                data = self.sock.recv(4096)
                if not data:
                    break
                if self.manager is not None:
                    for _ in self.manager.filter(data):
                        pass  # bytes for the device: an emulated receiver takes no input
                    pending = self.manager.suboption  # an open IAC SB ... (None: none open)
                    if pending is not None and len(pending) > MAX_SUBNEGOTIATION:
                        self.cut = f"a Telnet subnegotiation longer than {MAX_SUBNEGOTIATION} bytes (IAC SB without IAC SE)"
                    if self.cut is not None:
                        break
        except OSError:
            pass
        except Exception as exc:  # noqa: BLE001 - a malformed request must not kill the thread silently
            self.cut = f"bad RFC 2217 request ({exc!r})"
        if self.cut is not None:
            self.port.notify(f"{self.port.label}: client {self.name}: {self.cut}; disconnecting")
        self._vanish()

    def _vanish(self) -> None:
        """The client closed or broke the connection: forget it, free its socket."""
        if not self.gone.is_set():
            self.gone.set()
            with self._cond:
                self._closing = True
                self._cond.notify()
            _shut(self.sock)
            self.port.forget(self)

    def close(self, deadline: float) -> None:
        """Send what is queued, wait for the client to hang up until ``deadline``
        (monotonic), then close the socket."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._sender.join(max(0.0, deadline - time.monotonic()))
        self.gone.wait(max(0.0, deadline - time.monotonic()))
        self.gone.set()
        _shut(self.sock)
        self._sender.join(1.0)
        self._reader.join(1.0)


def resolve(host: str, port: int | None, where: str) -> list:
    """getaddrinfo's TCP answers for ``host``; InputError ``WHERE: cannot resolve 'HOST': why``."""
    try:
        return socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:  # (UnicodeError: a name IDNA cannot encode, e.g. "a..b")
        reason = getattr(exc, "strerror", None) or exc
        raise InputError(f"{where}: cannot resolve {host!r}: {reason}") from None


def all_loopback(infos: list) -> bool:
    """True if every address of ``infos`` (getaddrinfo's answers) is a loopback address."""
    return bool(infos) and all(ipaddress.ip_address(i[4][0].split("%")[0]).is_loopback for i in infos)


def tcp_listener(host: str, port: int, where: str, backlog: int,
                 remote: str | None = None) -> socket.socket:
    """A socket listening on the first address ``host``:``port`` resolves to (the stream
    servers here, the control channel); InputError if ``host`` does not resolve, or, with
    ``remote`` (the refusal's text), if it resolves to an address that is not loopback
    (checked on the addresses it binds: one lookup), LinkError if it cannot be bound, each
    one line starting with ``where`` (``port SPEC`` ...)."""
    infos = resolve(host, port, where)
    if remote is not None and not all_loopback(infos):
        raise InputError(f"{where}: {remote}")
    family, _, _, _, sockaddr = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(sockaddr)
        sock.listen(backlog)
    except OSError as exc:
        sock.close()
        raise LinkError(f"{where}: cannot listen: {exc.strerror or exc}") from None
    return sock


#: A stream server's refusal of a host that is not loopback (``--serve-any-host`` allows it).
NOT_LOOPBACK = "{host} is not a loopback address; add --serve-any-host to serve other hosts"


class ServerPort(Port):
    """A stream served to TCP clients (see the module docstring). ``path`` is the URL a
    pyserial client opens (``rfc2217://127.0.0.1:40123`` or ``socket://...``)."""

    def __init__(self, label: str, spec: ServerSpec, settings: LineSettings | None = None,
                 serve_any_host: bool = False, notify: Callable[[str], None] | None = None) -> None:
        super().__init__(label)
        self.spec = spec
        self.settings = settings or LineSettings()
        self.notify = notify or (lambda _line: None)
        remote = None if serve_any_host else NOT_LOOPBACK.format(host=spec.host)
        self._listener = tcp_listener(spec.host, spec.port, f"port {spec.text}", backlog=8, remote=remote)
        self._listener.setblocking(False)  # the selector says when a client waits
        self._wake_r, self._wake_w = socket.socketpair()  # close() wakes the accept loop through it
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ)
        self._selector.register(self._wake_r, selectors.EVENT_READ)
        scheme = "rfc2217" if spec.kind == "rfc2217-server" else "socket"
        self.path = f"{scheme}://{format_addr(self._listener.getsockname())}"
        self.drain_wait = 0.0
        self._clients: list[ServedClient] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._left_written = 0  # counts of clients that left
        self._left_dropped = 0
        self._unheard = 0
        #: Connections closed at once: :data:`MAX_CLIENTS` were being served.
        self.clients_refused = 0
        self._acceptor = threading.Thread(target=self._accept_loop, name=f"{label} accept", daemon=True)
        self._acceptor.start()

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def set_drain_wait(self, seconds: float) -> None:
        self.drain_wait = seconds

    def _accept_loop(self) -> None:
        """Blocks until a client connects or :meth:`close` wakes it (no polling)."""
        while not any(key.fileobj is self._wake_r for key, _ in self._selector.select()):
            try:
                sock, addr = self._listener.accept()
            except BlockingIOError:  # the connection went before it was taken
                continue
            except OSError:
                return
            if self.clients >= MAX_CLIENTS:
                self.clients_refused += 1  # by this thread only; before the client sees its EOF
                n = self.clients_refused
                _shut(sock)
                if n <= NOTIFY_REFUSALS:
                    more = "; further refusals only counted" if n == NOTIFY_REFUSALS else ""
                    self.notify(f"{self.label}: client {format_addr(addr)} refused: {MAX_CLIENTS} clients are "
                                f"connected (at most {MAX_CLIENTS}){more}")
                continue
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = ServedClient(self, sock, addr)
            with self._lock:
                if self._stop.is_set():
                    sock.close()
                    return
                self._clients.append(client)
            self.notify(f"{self.label}: client {client.name} connected "
                        f"({self.spec.kind}, line {client.line.settings.describe()})")
            client.start()

    def forget(self, client: ServedClient) -> None:
        with self._lock:
            if client not in self._clients:
                return
            self._clients.remove(client)
            self._left_written += client.bytes_sent
            self._left_dropped += client.bytes_dropped
        unshown = client.setting_changes - NOTIFY_SETTING_CHANGES
        more = f", {unshown} more line-setting changes not reported" if unshown > 0 else ""
        self.notify(f"{self.label}: client {client.name} left: {client.bytes_sent} bytes sent, "
                    f"{client.bytes_dropped} dropped (line {client.line.settings.describe()}){more}")

    def write(self, data: bytes) -> int:
        with self._lock:
            clients = list(self._clients)
        if not clients:
            self._unheard += len(data)
        elif self.drain_wait > 0:
            # As fast as possible: give the slowest line up to the drain wait to make room.
            need = max(c.line.time_for(len(data)) for c in clients)
            if need > 0:
                time.sleep(min(need, self.drain_wait))
        for c in clients:
            c.offer(data)
        self._recount()
        return len(data) if clients else 0

    def _recount(self) -> None:
        with self._lock:
            live = list(self._clients)
            self.bytes_written = self._left_written + sum(c.bytes_sent for c in live)
            self.bytes_dropped = self._left_dropped + self._unheard + sum(c.bytes_dropped for c in live)

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):  # closed already
            self._wake_w.send(b"x")
        self._acceptor.join(1.0)
        for s in (self._listener, self._wake_r, self._wake_w, self._selector):
            s.close()
        with self._lock:
            clients = list(self._clients)
        deadline = time.monotonic() + CLOSE_LINGER_S
        for c in clients:
            c.close(deadline)
            self.forget(c)
        self._recount()
        if self.clients_refused > NOTIFY_REFUSALS:
            self.notify(f"{self.label}: {self.clients_refused} connections refused in all (at most {MAX_CLIENTS} clients at once)")


def escape_iac(data: bytes) -> bytes:
    """Telnet IAC escaping of stream data (every 0xFF doubled) by pyserial's
    ``PortManager.escape`` (a generator of single bytes that uses no state of its manager).
    It costs ~0.25 us per byte and runs in the emulator's write, at the epoch's deadline, so
    data without a 0xFF (every NMEA sentence: 7-bit text) is returned as it is."""
    if b"\xff" not in data:
        return data
    return b"".join(serial.rfc2217.PortManager.escape(None, data))


def _shut(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()


def format_addr(addr) -> str:
    host, port = addr[:2]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def stderr_notifier(prefix: str) -> Callable[[str], None]:
    """Client events as ``PREFIX: TEXT`` lines on stderr (from the server's threads). On a
    terminal the line first clears a live status line (``\\r`` + erase to end of line).

    Each line is one ``write`` (text and newline together): ``print`` writes them apart,
    and another thread's line could land between the two (two messages on one line)."""

    def notify(text: str) -> None:
        clear = "\r\x1b[K" if sys.stderr.isatty() else ""
        sys.stderr.write(f"{clear}{prefix}: {text}\n")
        sys.stderr.flush()

    return notify
