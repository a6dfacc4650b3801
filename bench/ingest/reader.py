"""One reader for every device: read in chunks, stamp, decode once, notify listeners.

Modelled on python-can's ``Notifier``/``Listener``: a :class:`Notifier` reads a set of
:class:`Device` objects and hands every read, decoded, to each :class:`Listener` (the
session writer of ``arva-bench log``, the dashboard's feeds). The **I/O thread** reads
every device with a descriptor in one selector and a port without one gets a small
thread, as docs/bench.md ("How devices are read") describes; the I/O thread does nothing
but read and stamp, so no device's decoding or disk writing delays another's stamp
(see ``switch_interval``). Besides:

* the **work thread** decodes each read (:mod:`bench.ingest.stamp`) and notifies the
  listeners, each device's reads in order; every :data:`TICK` it releases a quiet link's
  pending records and closes stale devices;
* the **opener** opens devices (opening can block): an absent one every
  :data:`RETRY_INTERVAL` s, a vanished one at once, keeping what the OS buffered meanwhile
  (``open_device(keep_input=True)``).

Times: ``mono`` is this process's ``time.monotonic()`` (s), ``utc`` POSIX seconds.
"""

from __future__ import annotations

import contextlib
import heapq
import logging
import os
import queue
import selectors
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import serial

from firmware_proto.errors import LinkError

from ..records import RecordDecoder, decoder_for
from ..session import DeviceSpec, Read
from ..transport import open_device
from .stamp import StampedDecoder

log = logging.getLogger(__name__)

#: Bytes asked for per read of a descriptor.
READ_CHUNK = 65536
#: Seconds between attempts to open an absent device.
RETRY_INTERVAL = 0.05
#: Seconds between ticks (idle decoder release, staleness checks, listener ``on_tick``).
TICK = 0.1
#: Thread switch interval (s) for a process that logs: see :class:`Notifier`.
SWITCH_INTERVAL = 0.0002
#: Read timeout (s) of ports read by a thread (no descriptor).
THREAD_READ_TIMEOUT = 0.1


@dataclass
class DeviceStats:
    """Counters of one device since its reader started (ints: a torn read is impossible)."""

    reads: int = 0
    bytes: int = 0
    records: int = 0
    gaps: int = 0
    connected: bool = False
    last_data_mono: float | None = None


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """``up`` (first open), ``unavailable`` (cannot open yet; again when the reason changes),
    ``gap`` (lost or stale: closed), ``reconnect`` (open again after a gap)."""

    kind: str
    mono: float
    reason: str = ""


class Device:
    """One device's decoder (with the stamp rule) and counters."""

    def __init__(self, spec: DeviceSpec) -> None:
        self.spec = spec
        self.decoder: RecordDecoder = decoder_for(spec.kind, spec.format)
        self.stamper = StampedDecoder(self.decoder, spec.baudrate)
        self.stats = DeviceStats()
        self.opens = 0
        self.reconnects = 0
        self.cut_at_stop = 0
        self.reason = ""  # of the last link event

    def ingest(self, data: bytes, mono: float, utc: float) -> Read:
        """Decode one read stamped at its return."""
        records = self.stamper.feed(data, mono, utc)
        st = self.stats
        st.reads += 1
        st.bytes += len(data)
        st.records += len(records)
        st.last_data_mono = mono
        return Read(mono, utc, data, records)

    def idle(self, mono: float, utc: float) -> Read:
        records = self.stamper.idle(mono, utc)
        self.stats.records += len(records)
        return Read(mono, utc, b"", records)

    def stop(self, mono: float, utc: float) -> Read:
        """The reading stops: pending records; a sentence cut by the stop is counted in
        ``cut_at_stop`` (bytes), not flagged as an error."""
        records, self.cut_at_stop = self.stamper.stop(mono, utc)
        self.stats.records += len(records)
        return Read(mono, utc, b"", records)


class Listener:
    """Receives what a :class:`Notifier` reads; every method runs in the notifier's work
    thread. Override what you need."""

    def on_read(self, device: Device, read: Read) -> None:
        """A read and the records it completed (``read.data`` empty: released by idle/end)."""

    def on_link(self, device: Device, event: LinkEvent) -> None:
        """The device's link changed."""

    def on_tick(self, mono: float) -> None:
        """About every :data:`TICK` s, data or not."""

    def stop(self) -> None:
        """The notifier stopped: nothing more will come."""


class _Port:
    """An open port in the loop: read by descriptor, or by a thread."""

    def __init__(self, device: Device, port: serial.SerialBase) -> None:
        self.device = device
        self.port = port
        try:
            self.fd: int | None = port.fileno()
        except (AttributeError, NotImplementedError, OSError, ValueError, serial.SerialException):
            self.fd = None
        self.quiet_since = time.monotonic()
        self.thread: threading.Thread | None = None
        self.closed = False
        self.closing = False  # a stale close was asked for

    def close(self) -> None:
        self.closed = True
        with contextlib.suppress(serial.SerialException, OSError):
            self.port.close()


class Notifier:
    """Reads ``devices`` until :meth:`stop`, notifying ``listeners``.

    ``stale_after`` (s, None: never): a device open but silent that long is closed and
    reopened (a ``gap`` with that reason, then ``reconnect``). ``on_error(exc)``: a
    listener raised :class:`LinkError`, a full disk (it is then removed; the others keep
    receiving). ``switch_interval`` (s, None: leave it): the interpreter's thread switch
    interval is lowered to it at :meth:`start` (a process-wide setting, for a command
    whose process only logs), so that the I/O thread, woken by data, gets the GIL from
    the decoding thread within that time.
    """

    def __init__(self, devices: Iterable[Device], listeners: Iterable[Listener] = (),
                 stale_after: float | None = None, on_error: Callable[[Exception], None] | None = None,
                 name: str = "ingest", switch_interval: float | None = None) -> None:  # fmt: skip
        self.devices = list(devices)
        self._listeners: tuple[Listener, ...] = tuple(listeners)
        self.stale_after = stale_after
        self.on_error = on_error
        self.switch_interval = switch_interval
        self._stop = threading.Event()
        self._work: queue.SimpleQueue = queue.SimpleQueue()  # -> the work thread
        self._io_inbox: queue.SimpleQueue = queue.SimpleQueue()  # -> the I/O thread (plus a wake-up)
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._open_requests: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._work_loop, name=name, daemon=True)
        self._io = threading.Thread(target=self._io_loop, name=f"{name}-io", daemon=True)
        self._opener = threading.Thread(target=self._open_loop, name=f"{name}-open", daemon=True)
        self._ports: dict[Device, _Port] = {}  # the work thread's view: open ports
        self._unavailable: dict[Device, str] = {}

    # -- lifetime --------------------------------------------------------------------------
    def start(self) -> None:
        if self.switch_interval is not None:
            sys.setswitchinterval(self.switch_interval)
        self.thread.start()
        self._io.start()
        self._opener.start()
        for dev in self.devices:
            self._open_requests.put(dev)

    def request_stop(self) -> None:
        self._stop.set()
        self._wake()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop reading, close every port, deliver every read already taken and flush the
        decoders (their last records are delivered before this returns, unless a thread
        needs more than ``timeout`` s: give a long one when nothing may be lost)."""
        self.request_stop()
        self.join(timeout)

    def join(self, timeout: float = 5.0) -> None:
        for t in (self._io, self.thread, self._opener):
            if t.is_alive():
                t.join(timeout)
        if not any(t.is_alive() for t in (self._io, self.thread, self._opener)) and self._wake_w >= 0:
            self._close_unclaimed()
            os.close(self._wake_r)
            os.close(self._wake_w)
            self._wake_r = self._wake_w = -1  # closed only once nobody can write to it

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # already awake (pipe full)
            os.write(self._wake_w, b"x")

    # -- the I/O thread: wait, read, stamp; nothing else ------------------------------------
    def _io_loop(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._wake_r, selectors.EVENT_READ, None)
        work = self._work
        ports: list[_Port] = []
        try:
            while not self._stop.is_set():
                ready = sel.select(timeout=TICK)
                mono, utc = time.monotonic(), time.time()  # one stamp for every ready device
                for key, _ in ready:
                    p = key.data
                    if p is None:
                        with contextlib.suppress(BlockingIOError):  # emptied
                            while os.read(self._wake_r, 4096):
                                pass
                        continue
                    try:
                        data = os.read(p.fd, READ_CHUNK)
                    except BlockingIOError:
                        continue
                    except OSError as exc:
                        self._io_close(sel, ports, p, exc.strerror or str(exc))
                        continue
                    if not data:
                        self._io_close(sel, ports, p, "end of file (the device closed)")
                        continue
                    work.put(("read", p, data, mono, utc))
                for item in _drained(self._io_inbox):
                    match item:
                        case ("open", p):
                            ports[:] = [q for q in ports if not q.closed]  # ports read by threads close themselves
                            ports.append(p)
                            work.put(("up", p))  # before any of its reads
                            if p.fd is not None:
                                sel.register(p.fd, selectors.EVENT_READ, p)
                            else:
                                p.thread = threading.Thread(target=self._thread_read, args=(p,),
                                                            name=f"read-{p.device.spec.name}", daemon=True)  # fmt: skip
                                p.thread.start()
                        case ("close", p, reason) if p in ports:
                            self._io_close(sel, ports, p, reason)
        finally:
            for p in ports:
                p.close()
            for p in ports:
                if p.thread is not None:
                    p.thread.join(1.0)
            sel.close()
            work.put(("end",))
            self._close_unclaimed()

    def _close_unclaimed(self) -> None:
        """Ports the opener handed over after the I/O thread stopped."""
        for item in _drained(self._io_inbox):
            if item[0] == "open":
                item[1].close()

    def _io_close(self, sel, ports: list[_Port], p: _Port, reason: str) -> None:
        if p.fd is not None:
            with contextlib.suppress(KeyError, ValueError):
                sel.unregister(p.fd)
        p.close()
        if p in ports:
            ports.remove(p)
        self._work.put(("lost", p, reason))

    def _thread_read(self, p: _Port) -> None:
        """A port without a descriptor: block for the first byte, take what else waits."""
        port, work = p.port, self._work
        try:
            while not p.closed:
                data = port.read(1)  # blocks up to the port's timeout
                if not data:
                    continue
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, READ_CHUNK))
                work.put(("read", p, data, time.monotonic(), time.time()))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            if not p.closed:
                p.close()
                work.put(("lost", p, str(exc) or type(exc).__name__))

    # -- the work thread: decode, notify, tick ------------------------------------------------
    def _notify(self, method: str, *args) -> None:
        """``listener.<method>(*args)`` for each listener; one that raises is dropped."""
        for listener in self._listeners:
            try:
                getattr(listener, method)(*args)
            except LinkError as exc:
                self._dropped(listener, exc)
            except Exception as exc:  # noqa: BLE001 - a listener's bug must not stop the others
                where = f"{args[0].spec.name}: " if args and isinstance(args[0], Device) else ""
                log.exception("listener %r failed: %s%s", listener, where, method)
                self._dropped(listener, LinkError(f"{where}{type(listener).__name__} failed: {exc!r}"))

    def _ingest(self, p: _Port, data: bytes, mono: float, utc: float) -> Read:
        try:
            return p.device.ingest(data, mono, utc)
        except Exception:  # noqa: BLE001 - a decoder bug: keep the bytes, lose only the records
            log.exception("decoding a read of %s failed; its bytes are kept without records", p.device.spec.name)
            return Read(mono, utc, data, [])

    def _dropped(self, listener: Listener, exc: Exception) -> None:
        self._listeners = tuple(li for li in self._listeners if li is not listener)
        if self.on_error is not None:
            self.on_error(exc)

    def _link(self, device: Device, kind: str, reason: str = "") -> None:
        device.reason = reason
        self._notify("on_link", device, LinkEvent(kind, time.monotonic(), reason))

    def _work_loop(self) -> None:
        work = self._work
        next_tick = time.monotonic() + TICK
        try:
            while True:
                try:
                    item = work.get(timeout=max(0.0, next_tick - time.monotonic()))
                except queue.Empty:
                    item = None
                match item:
                    case ("read", p, data, mono, utc):
                        p.quiet_since = mono
                        self._notify("on_read", p.device, self._ingest(p, data, mono, utc))
                    case ("up", p):
                        self._up(p)
                    case ("lost", p, reason):
                        self._lost(p, reason)
                    case ("unavailable", dev, reason) if not dev.opens:  # after a gap, the gap says so
                        self._link(dev, "unavailable", reason)
                    case ("end",):
                        break
                now = time.monotonic()
                if now >= next_tick:
                    next_tick = now + TICK
                    self._idle(now)
        finally:
            mono, utc = time.monotonic(), time.time()
            for dev in self.devices:
                self._notify("on_read", dev, dev.stop(mono, utc))
                dev.stats.connected = False
            self._notify("stop")

    def _up(self, p: _Port) -> None:
        dev = p.device
        if self._stop.is_set():
            return
        self._ports[dev] = p
        dev.opens += 1
        dev.stats.connected = True
        p.quiet_since = time.monotonic()
        dev.reconnects = dev.opens - 1  # every open after the first
        self._link(dev, "reconnect" if dev.reconnects else "up")

    def _lost(self, p: _Port, reason: str) -> None:
        dev = p.device
        if self._ports.get(dev) is not p:
            return  # already handled (a stale close racing a read error)
        del self._ports[dev]
        dev.stats.connected = False
        if self._stop.is_set():
            return
        dev.stats.gaps += 1
        self._link(dev, "gap", reason)
        self._open_requests.put(dev)  # reopen at once

    def _idle(self, now: float) -> None:
        utc = time.time()
        for p in list(self._ports.values()):
            if now - p.quiet_since >= TICK:
                read = p.device.idle(now, utc)
                if read.records:
                    self._notify("on_read", p.device, read)
            if self.stale_after is not None and now - p.quiet_since > self.stale_after and not p.closing:
                p.closing = True
                reason = f"no data for {self.stale_after:g} s: reopening"
                if p.fd is not None:
                    self._io_inbox.put(("close", p, reason))
                    self._wake()
                else:
                    p.close()
                    self._lost(p, reason)
        self._notify("on_tick", now)

    # -- the opener thread --------------------------------------------------------------------
    def _open_loop(self) -> None:
        due: list[tuple[float, int, Device]] = []
        while not self._stop.is_set():
            timeout = min(TICK, max(0.0, due[0][0] - time.monotonic())) if due else TICK
            try:
                dev = self._open_requests.get(timeout=timeout)
                heapq.heappush(due, (time.monotonic(), id(dev), dev))
            except queue.Empty:
                pass
            while due and due[0][0] <= time.monotonic() and not self._stop.is_set():
                _, _, dev = heapq.heappop(due)
                spec = dev.spec
                try:
                    port = open_device(spec.url, baudrate=spec.baudrate, timeout=THREAD_READ_TIMEOUT, keep_input=True)
                except (serial.SerialException, OSError, ValueError) as exc:
                    reason = str(exc) or type(exc).__name__
                    if self._unavailable.get(dev) != reason:
                        self._unavailable[dev] = reason
                        self._work.put(("unavailable", dev, reason))
                    heapq.heappush(due, (time.monotonic() + RETRY_INTERVAL, id(dev), dev))
                    continue
                self._unavailable.pop(dev, None)
                self._io_inbox.put(("open", _Port(dev, port)))
                self._wake()


def _drained(q: queue.Queue):
    """The items waiting in ``q`` now, without blocking."""
    while True:
        try:
            yield q.get_nowait()
        except queue.Empty:
            return
