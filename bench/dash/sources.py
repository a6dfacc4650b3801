"""Background readers for the dashboard: one thread per device (or per replayed session).

A :class:`DeviceFeed` owns one device's decoder (:mod:`bench.records`, the same decoders
``arva-bench log`` uses) and link counters, and turns reads into messages
(:mod:`bench.dash.messages`) posted with ``post`` -- the app's ``post_message``, which is
thread-safe; threads touch nothing else of the UI. It also hands every read to an
optional recorder (:class:`bench.dash.recorder.SessionRecorder`) set by the app.

* :class:`LiveSource` opens a path or pyserial URL with :func:`bench.transport.open_device`
  and reads it; when the device fails, vanishes or stays silent longer than
  ``stale_after`` seconds, it closes and reopens it, with backoff (0.1 s doubling to 2 s)
  while opening fails -- a stale source reconnects by itself.
* :class:`ReplaySource` replays a session directory's raw reads in-process, with their
  recorded timing (``speed`` times real time; 0 as fast as possible), merged across
  devices by the logger's monotonic clock as ``arva-bench replay`` does.
* :class:`SceneTruth`: for an ``arvaemu://`` source, the true poses of the receiver and
  transmitters at each epoch, from the scene itself (epoch k is at t = k / rate_hz).
"""

from __future__ import annotations

import heapq
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path

import serial

from emulator.scene.reader import default_scene, load_scene
from firmware_proto.errors import InputError

from ..logger import BACKOFF_MAX, BACKOFF_START, DeviceSpec
from ..records import ArvaRecords, GroundTruthRecords, decoder_for
from ..session import read_raw
from ..transport import open_device
from .messages import AttitudeReceived, EpochReceived, FixReceived, LinkCounters, LinkStatus, TruthPose

#: Read timeout (s): how often a silent device is checked for staleness and stop requests.
READ_TIMEOUT = 0.1
#: At most this many LinkStatus messages per second per device while data flows.
STATUS_INTERVAL = 0.25
#: Records posted per second per device at most (a burst of POST_BURST passes at once).
#: Beyond that (an emulator or a replay at speed 0) the UI gets the latest record at
#: least every STATUS_INTERVAL, with running counts so rates stay exact, and the
#: app's message queue stays bounded. Counters and recordings see every record.
POST_RATE = 30.0
POST_BURST = 10.0
SEQ_MODULO = 65536

Post = Callable[[object], object]


class SceneTruth:
    """True poses for an ``arvaemu://SCENE[?receiver=ID...]`` source: :class:`TruthPose`
    messages (``via="scene"``) of the receiver and every transmitter at each epoch's
    time, posted just before the epoch. Not for closed-loop receivers, whose poses the
    scene does not know in advance (``for_url`` returns None)."""

    def __init__(self, scene, index: int, rx_role: str) -> None:
        self.rx = scene.receivers[index]
        self.transmitters = scene.transmitters
        self.rate = scene.rate_hz
        self.rx_role = rx_role
        self.reset()

    @classmethod
    def for_url(cls, url: str, rx_role: str) -> SceneTruth | None:
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "arvaemu":
            return None
        path = parts.netloc + parts.path
        opts = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
        try:
            scene = default_scene() if path in ("", "default") else load_scene(path)
        except (InputError, OSError):
            return None  # the port itself will report the problem
        ids = [rx.id for rx in scene.receivers]
        index = ids.index(int(opts["receiver"])) if opts.get("receiver", "").isdigit() and int(opts["receiver"]) in ids else 0
        if getattr(scene.receivers[index], "vehicle", None) is not None:
            return None
        return cls(scene, index, rx_role)

    def reset(self) -> None:
        """A new connection: the emulated receiver starts again at epoch 0."""
        self._k: int | None = None
        self._seq = 0

    def on_epoch(self, seq: int) -> int:
        """Follow the epoch counter (seq is k modulo 65536); returns k."""
        k = seq if self._k is None else self._k + (seq - self._seq) % SEQ_MODULO
        self._k, self._seq = k, seq
        return k

    def poses(self, k: int, mono: float) -> list[TruthPose]:
        """The receiver's and transmitters' poses at epoch k (t = k / rate_hz)."""
        t = k / self.rate
        pos, q = self.rx.trajectory.at([t])
        out = [TruthPose(self.rx_role, tuple(pos[0]), tuple(q[0]), "scene", mono)]
        for tx in self.transmitters:
            p, tq = tx.trajectory.at([t])
            out.append(TruthPose(f"tx{tx.id}", tuple(p[0]), tuple(tq[0]), "scene", mono))
        return out


class DeviceFeed:
    """Decoder, counters and messages of one device; used by one thread at a time."""

    def __init__(self, spec: DeviceSpec, post: Post, truth: SceneTruth | None = None) -> None:
        self.spec = spec
        self.post = post
        self.decoder = decoder_for(spec.kind, spec.format)
        self.truth = truth
        self.recorder = None  # set and cleared by the app (an attribute write is atomic)
        self.reads = 0
        self.bytes = 0
        self.records = 0
        self.checksum_errors = 0
        self.errors = 0
        self.rejected_bytes = 0
        self.reconnects = 0
        self.last_data_mono: float | None = None
        self.state = "connecting"
        self.reason = ""
        self._last_status = -1e9
        self._dirty = False
        self._counts = {"epoch": 0, "GGA": 0, "RMC": 0, "GLL": 0, "attitude": 0}
        self._tokens = POST_BURST
        self._token_mono: float | None = None
        self._held: list | None = None  # the latest record's messages not posted yet

    # -- data ----------------------------------------------------------------------------
    def received(self, data: bytes, mono: float, utc: float) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.raw(self.spec.name, data, mono, utc)
        self.reads += 1
        self.bytes += len(data)
        self.last_data_mono = mono
        self._handle(self.decoder.feed(data), mono)
        self._dirty = True
        self.status(mono)

    def idle(self) -> None:
        mono = time.monotonic()
        if isinstance(self.decoder, ArvaRecords):
            self._handle(self.decoder.idle(), mono)
        if self._dirty or self._held is not None:
            self.status(mono)

    def flush(self) -> None:
        self._handle(self.decoder.flush(), time.monotonic())
        self._release()

    def _handle(self, records: list[dict], mono: float) -> None:
        name, role = self.spec.name, self.spec.role
        for rec in records:
            err = rec.get("error")
            if err is not None:
                if isinstance(err, dict):  # ground truth: counter increments
                    self.checksum_errors += err.get("bad_checksum", 0)
                    self.errors += sum(v for k, v in err.items() if k != "junk_bytes")
                else:
                    self.errors += 1
                    self.checksum_errors += err == "BAD_CHECKSUM"
                    self.rejected_bytes += rec.get("length", 0)
                continue
            self.records += 1
            counts = self._counts
            if "seq" in rec:
                counts["epoch"] += 1
                k = self.truth.on_epoch(rec["seq"]) if self.truth is not None else 0
                slots = [None if s is None else tuple(s) for s in rec["slots"]]
                epoch = EpochReceived(name, role, rec["seq"], slots, mono, rec["complete"], rec.get("gap", 0),
                                      count=counts["epoch"])  # fmt: skip
                truth = self.truth

                def make(truth=truth, k=k, epoch=epoch, mono=mono) -> list:
                    return ([] if truth is None else truth.poses(k, mono)) + [epoch]

                self._offer(make, mono)
            elif "sentence" in rec:
                if rec["sentence"] in counts:
                    counts[rec["sentence"]] += 1
                fixes = counts["GGA"] or counts["RMC"] or counts["GLL"]
                self._offer(lambda rec=rec, n=fixes, mono=mono: [FixReceived(name, role, rec, mono, count=n)], mono)
            elif "q" in rec:
                counts["attitude"] += 1
                msg = AttitudeReceived(name, role, rec["heading"], rec["roll"], rec["pitch"], rec["q"], mono,
                                       count=counts["attitude"])  # fmt: skip
                self._offer(lambda msg=msg: [msg], mono)

    def _offer(self, make, mono: float) -> None:
        """Post one record's messages (``make()``), unless the token bucket is empty:
        then hold them, replacing an older held record, until :meth:`status`."""
        if self._token_mono is not None:
            self._tokens = min(POST_BURST, self._tokens + (mono - self._token_mono) * POST_RATE)
        self._token_mono = mono
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            self._held = None
            for msg in make():
                self.post(msg)
        else:
            self._held = make  # built only if it is ever posted

    def _release(self) -> None:
        held, self._held = self._held, None
        if held is not None:
            for msg in held():
                self.post(msg)

    # -- link state ----------------------------------------------------------------------
    def counters(self) -> LinkCounters:
        dec = self.decoder
        if isinstance(dec, ArvaRecords):
            st = dec.decoder.stats
            seq_gaps, dropped = st.seq_gaps, st.garbage_bytes + self.rejected_bytes
        else:
            assert isinstance(dec, GroundTruthRecords)
            seq_gaps, dropped = 0, dec.reader.stats["junk_bytes"]
        return LinkCounters(
            reads=self.reads, bytes=self.bytes, records=self.records, checksum_errors=self.checksum_errors,
            errors=self.errors, seq_gaps=seq_gaps, dropped_bytes=dropped, reconnects=self.reconnects,
            last_data_mono=self.last_data_mono,
        )  # fmt: skip

    def status(self, mono: float | None = None, force: bool = False) -> None:
        mono = time.monotonic() if mono is None else mono
        if not force and mono - self._last_status < STATUS_INTERVAL:
            return
        self._last_status = mono
        self._dirty = False
        self._release()
        s = self.spec
        self.post(LinkStatus(s.name, s.kind, s.role, s.url, self.state, self.counters(), self.reason))

    def set_state(self, state: str, reason: str = "") -> None:
        self.state, self.reason = state, reason
        self.status(force=True)

    def event(self, kind: str, **fields) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.event(kind, self.spec.name, **fields)


class _SourceThread:
    """One background thread feeding the app; started, stopped and joined by it."""

    def __init__(self, name: str) -> None:
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def start(self) -> None:
        self.thread.start()

    def request_stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float) -> None:
        if self.thread.is_alive():
            self.thread.join(timeout)


class LiveSource(_SourceThread):
    """A thread reading one device, reopening it when it fails or goes stale."""

    def __init__(self, feed: DeviceFeed, stale_after: float = 3.0) -> None:
        self.feed = feed
        self.stale_after = stale_after
        super().__init__(f"dash-{feed.spec.name}")

    @property
    def feeds(self) -> list[DeviceFeed]:
        return [self.feed]

    def _run(self) -> None:
        feed, spec = self.feed, self.feed.spec
        backoff = BACKOFF_START
        opened_before = False
        while not self._stop.is_set():
            try:
                port = open_device(spec.url, baudrate=spec.baudrate, timeout=READ_TIMEOUT)
            except (serial.SerialException, OSError, ValueError) as exc:
                if feed.state != "down" or feed.reason != str(exc):
                    feed.event("unavailable", reason=str(exc))
                    feed.set_state("down", str(exc))
                self._stop.wait(backoff)
                backoff = min(backoff * 2, BACKOFF_MAX)
                continue
            if opened_before:
                feed.reconnects += 1
                feed.event("reconnect")
            opened_before = True
            backoff = BACKOFF_START
            if feed.truth is not None:
                feed.truth.reset()
            feed.set_state("up")
            reason = ""
            quiet_since = time.monotonic()
            try:
                while not self._stop.is_set():
                    data = port.read(port.in_waiting or 1)
                    now = time.monotonic()
                    if data:
                        feed.received(data, now, time.time())
                        quiet_since = now
                        continue
                    feed.idle()
                    if now - quiet_since > self.stale_after:
                        reason = f"no data for {self.stale_after:g} s: reopening"
                        break
            except (serial.SerialException, OSError) as exc:
                reason = str(exc) or type(exc).__name__
            finally:
                try:
                    port.close()
                except (serial.SerialException, OSError):
                    pass
            if self._stop.is_set():
                break
            feed.event("gap", reason=reason)
            feed.set_state("down", reason)
            self._stop.wait(backoff)
        feed.flush()


class ReplaySource(_SourceThread):
    """A thread replaying a session directory's devices with their recorded timing."""

    def __init__(self, directory: str | Path, feeds: list[DeviceFeed], speed: float = 1.0) -> None:
        self.directory = Path(directory)
        self._feeds = {f.spec.name: f for f in feeds}
        self.speed = speed
        super().__init__("dash-replay")

    @property
    def feeds(self) -> list[DeviceFeed]:
        return list(self._feeds.values())

    def _run(self) -> None:
        reads = {}
        for name, feed in self._feeds.items():
            try:
                reads[name] = read_raw(self.directory / f"{name}.raw").reads
            except (InputError, OSError) as exc:
                feed.set_state("down", str(exc))
                reads[name] = []
            else:
                feed.set_state("up")
        queue = [(r[0].mono, i, n, 0) for i, (n, r) in enumerate(reads.items()) if r]
        heapq.heapify(queue)
        t0 = min((q[0] for q in queue), default=0.0)
        start = time.monotonic()
        while queue and not self._stop.is_set():
            mono, i, name, j = heapq.heappop(queue)
            if self.speed > 0:
                delay = start + (mono - t0) / self.speed - time.monotonic()
                while delay > 0 and not self._stop.is_set():
                    self._stop.wait(min(delay, READ_TIMEOUT))
                    for feed in self._feeds.values():
                        feed.idle()
                    delay = start + (mono - t0) / self.speed - time.monotonic()
                if self._stop.is_set():
                    break
            self._feeds[name].received(reads[name][j].data, time.monotonic(), time.time())
            if j + 1 < len(reads[name]):
                heapq.heappush(queue, (reads[name][j + 1].mono, i, name, j + 1))
        for feed in self._feeds.values():
            feed.flush()
            if not self._stop.is_set():
                feed.set_state("ended", "end of the session")
