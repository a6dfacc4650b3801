"""Logging devices into a session: one reader thread per device, reconnecting by itself.

Each :class:`DeviceLogger` owns one device (a path or pyserial URL). A supervisor thread
opens it, runs a :class:`serial.threaded.ReaderThread` whose protocol stamps every read
with the monotonic and UTC time, writes it raw to the session and decodes it into
records. When the device goes away (unplugged cable, closed pty) the reader thread ends,
a ``gap`` event is recorded, and the supervisor retries with exponential backoff
(0.1 s doubling to 2 s) until the device is back (``reconnect`` event) or the session
stops. The other devices keep logging meanwhile.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import serial
import serial.threaded

from firmware_proto.errors import LinkError

from .records import RecordDecoder, decoder_for
from .session import SessionWriter
from .transport import open_device

BACKOFF_START = 0.1
BACKOFF_MAX = 2.0


@dataclass
class DeviceSpec:
    """A device to log: ``name`` in the session (``arva``, ``gps-rx``, ``attitude-tx1``),
    ``kind`` (arva, gps, attitude), ``role`` (``rx``, ``rx<id>`` or ``tx<id>``), ``format``
    (None: the kind's default; ``mavlink`` for a MAVLink attitude source)."""

    name: str
    kind: str
    url: str
    role: str = "rx"
    baudrate: int = 115200
    format: str | None = None

    def manifest(self) -> dict:
        out = {"kind": self.kind, "url": self.url, "role": self.role, "baudrate": self.baudrate}
        if self.format is not None:
            out["format"] = self.format
        return out


@dataclass
class DeviceStats:
    reads: int = 0
    bytes: int = 0
    records: int = 0
    gaps: int = 0
    connected: bool = False
    last_data_mono: float | None = None
    decoder: dict = field(default_factory=dict)


class _Protocol(serial.threaded.Protocol):
    """Stamps, stores and decodes every read (runs in the ReaderThread)."""

    def __init__(self, owner: "DeviceLogger") -> None:
        self.owner = owner

    def data_received(self, data: bytes) -> None:
        self.owner.received(data, time.monotonic(), time.time())

    def connection_lost(self, exc: BaseException | None) -> None:
        self.owner.lost(exc)


class DeviceLogger:
    def __init__(self, spec: DeviceSpec, writer: SessionWriter, on_fatal, on_fix=None) -> None:
        """``on_fatal(LinkError)``: the disk failed. ``on_fix(lat, lon, alt_hae)``: each
        valid GGA fix with a height from a receiver's GPS (for the session's origin)."""
        self.spec = spec
        self.writer = writer
        self.decoder: RecordDecoder = decoder_for(spec.kind, spec.format)
        self.stats = DeviceStats()
        self._on_fatal = on_fatal
        self._on_fix = on_fix if spec.kind == "gps" and spec.role.startswith("rx") else None
        self._stop = threading.Event()
        self._lost = threading.Event()
        self._lock = threading.Lock()  # the decoder is fed from reader threads one at a time
        self._thread = threading.Thread(target=self._supervise, name=f"log-{spec.name}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._lost.set()
        self._thread.join(timeout=5)
        try:
            with self._lock:
                self._store(self.decoder.flush(), time.monotonic(), time.time())
        except LinkError as exc:  # the disk filled up: report it, let the session close
            self._on_fatal(exc)

    # -- called from the reader thread ---------------------------------------------
    def received(self, data: bytes, mono: float, utc: float) -> None:
        try:
            with self._lock:
                self.writer.raw(self.spec.name, data, mono, utc)
                self._store(self.decoder.feed(data), mono, utc)
                self.stats.reads += 1
                self.stats.bytes += len(data)
                self.stats.last_data_mono = mono
        except LinkError as exc:  # the disk: stop everything, keep what was written
            self._on_fatal(exc)
            raise

    def _store(self, records: list[dict], mono: float, utc: float) -> None:
        for rec in records:
            self.writer.record(self.spec.name, {"mono": round(mono, 6), "utc": round(utc, 6), **rec})
            if self._on_fix is not None and rec.get("sentence") == "GGA" and rec.get("valid") \
                    and rec.get("alt_hae") is not None:
                self._on_fix(rec["lat"], rec["lon"], rec["alt_hae"])
        self.stats.records += len(records)

    def lost(self, exc: BaseException | None) -> None:
        self._lost.set()

    # -- supervisor ------------------------------------------------------------------
    def _event(self, kind: str, **fields) -> None:
        try:
            self.writer.event(kind, device=self.spec.name, **fields)
        except LinkError as exc:
            self._on_fatal(exc)
            self._stop.set()

    def _supervise(self) -> None:
        backoff = BACKOFF_START
        first = True
        while not self._stop.is_set():
            try:
                port = open_device(self.spec.url, baudrate=self.spec.baudrate, timeout=0.1)
            except (serial.SerialException, OSError, ValueError) as exc:
                if first:
                    self._event("unavailable", reason=str(exc))
                    first = False
                self._stop.wait(backoff)
                backoff = min(backoff * 2, BACKOFF_MAX)
                continue
            if not first:
                self._event("reconnect")
            first = False
            backoff = BACKOFF_START
            self.stats.connected = True
            self._lost.clear()
            reader = serial.threaded.ReaderThread(port, lambda: _Protocol(self))
            reader.daemon = True
            reader.start()
            self._lost.wait()
            reader.stop()
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass
            self.stats.connected = False
            if not self._stop.is_set():
                self.stats.gaps += 1
                self._event("gap")
