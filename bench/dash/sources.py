"""Readers for the dashboard: the bench's one ingest (:mod:`bench.ingest`), with a
:class:`DeviceFeed` listener per device that turns reads into messages (docs/dashboard.md,
"How it works"). :class:`LiveSource` reads the live devices, :class:`ReplaySource` a
session directory; :class:`SceneTruth` gives an ``arvaemu://`` source's true poses.
"""

from __future__ import annotations

import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path

from msgspec.structs import replace
from serial import SerialException

from firmware_proto.errors import InputError

from emulator.urlhandler.protocol_arvaemu import parse_url

from ..ingest.pacer import load_reads, pace
from ..ingest.reader import Device, DeviceSpec, LinkEvent, Listener, Notifier, Read
from ..ingest.stamp import Stamped
from ..records import ArvaRecords, GroundTruthRecords
from .messages import AttitudeReceived, EpochReceived, FixReceived, LinkCounters, LinkStatus, TruthPose

#: Seconds between idle ticks of a replay (a quiet link's epochs are released, statuses posted).
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
        if urllib.parse.urlsplit(url).scheme != "arvaemu":
            return None
        try:
            u = parse_url(url)
        except (SerialException, OSError):
            return None  # the port itself will report the problem
        if getattr(u.scene.receivers[u.index], "vehicle", None) is not None:
            return None
        return cls(u.scene, u.index, rx_role)

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
        out = [TruthPose(self.rx_role, pos[0], q[0], "scene", mono)]  # made float tuples by the message
        for tx in self.transmitters:
            p, tq = tx.trajectory.at([t])
            out.append(TruthPose(f"tx{tx.id}", p[0], tq[0], "scene", mono))
        return out


class DeviceFeed(Listener):
    """Messages and link counters of one device: a listener of the notifier (or replay
    pacer) that reads and decodes it. Calls come from that one thread, which posts
    :mod:`bench.dash.messages` with ``post`` (the app's thread-safe ``post_message``) and
    touches nothing else of the UI; reads and link events also go to the app's recorder
    (:class:`bench.dash.recorder.SessionRecorder`) while one is set."""

    def __init__(self, spec: DeviceSpec, post: Post, truth: SceneTruth | None = None) -> None:
        self.spec = spec
        self.device = Device(spec)
        self.post = post
        self.truth = truth
        self.recorder = None  # set and cleared by the app (an attribute write is atomic: read it once)
        self.checksum_errors = 0
        self.errors = 0
        self.rejected_bytes = 0
        self.state = "connecting"
        self.reason = ""
        self._last_status = -1e9
        self._dirty = False
        self._counts = {"epoch": 0, "GGA": 0, "RMC": 0, "GLL": 0, "attitude": 0}  # every record is one of these
        self._tokens = POST_BURST
        self._token_mono: float | None = None
        self._held: list | None = None  # the latest record's messages not posted yet

    # -- from the reader -------------------------------------------------------------------
    def on_read(self, device: Device, read: Read) -> None:
        if device is not self.device:  # a notifier tells every listener of every device
            return
        if (recorder := self.recorder) is not None:
            recorder.on_read(device, read)
        self._handle(read.records)
        if read.data:  # reads, bytes and the last data's time are the device's stats
            self._dirty = True
            self.status(read.mono)

    def on_link(self, device: Device, event: LinkEvent) -> None:
        if device is not self.device:
            return
        if (recorder := self.recorder) is not None:
            recorder.on_link(device, event)
        if event.kind in ("up", "reconnect"):
            if self.truth is not None:
                self.truth.reset()  # a new connection: the emulated receiver starts again
            self.set_state("up")
        elif event.kind == "gap" or (event.kind == "unavailable" and (self.state, self.reason) != ("down", event.reason)):
            self.set_state("down", event.reason)

    def on_tick(self, mono: float) -> None:
        if self._dirty or self._held is not None:
            self.status(mono)

    def stop(self) -> None:
        """The reading ended: post what is held back."""
        self._release()

    def _handle(self, records: list[Stamped]) -> None:
        name, role, counts, truth = self.spec.name, self.spec.role, self._counts, self.truth
        for stamped in records:
            rec, mono = stamped.record, stamped.mono
            if "suppressed" in rec or "error" in rec:
                self._count_errors(rec)
                continue
            if "seq" in rec:
                counts["epoch"] += 1
                k = truth.on_epoch(rec["seq"]) if truth is not None else 0
                epoch = EpochReceived(name, role, rec["seq"], rec["slots"], mono, rec["complete"], rec.get("gap", 0),
                                      count=counts["epoch"])  # fmt: skip

                def make(k=k, epoch=epoch, mono=mono) -> list:
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

    def _count_errors(self, rec: dict) -> None:
        """An error record, or a sum of them (``suppressed``: see :mod:`bench.ingest.stamp`).
        A receiver's error is a kind name, ground truth's a dict of counter increments."""
        kinds = rec["kinds"] if "suppressed" in rec else rec["error"]
        if self.spec.kind == "arva":
            kinds = {kinds: 1} if isinstance(kinds, str) else kinds
            self.errors += rec.get("suppressed", 1)
            self.checksum_errors += kinds.get("BAD_CHECKSUM", 0)
            self.rejected_bytes += rec.get("length", 0)
        else:
            self.checksum_errors += kinds.get("bad_checksum", 0)
            self.errors += sum(v for k, v in kinds.items() if k != "junk_bytes")

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
        dec = self.device.decoder
        if isinstance(dec, ArvaRecords):
            seq_gaps, dropped = dec.decoder.stats.seq_gaps, dec.decoder.stats.garbage_bytes + self.rejected_bytes
        else:
            assert isinstance(dec, GroundTruthRecords)
            seq_gaps, dropped = 0, dec.reader.stats["junk_bytes"]
        st = self.device.stats
        return LinkCounters(
            reads=st.reads, bytes=st.bytes, records=sum(self._counts.values()), checksum_errors=self.checksum_errors,
            errors=self.errors, seq_gaps=seq_gaps, dropped_bytes=dropped, reconnects=self.device.reconnects,
            last_data_mono=st.last_data_mono,
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


class LiveSource(Notifier):
    """Every live device of the dashboard read by one :class:`~bench.ingest.reader.Notifier`
    (one selector loop), each with its :class:`DeviceFeed` as listener; a device silent for
    ``stale_after`` seconds is closed and reopened."""

    def __init__(self, feeds: list[DeviceFeed], stale_after: float = 3.0) -> None:
        self.feeds = list(feeds)
        super().__init__([f.device for f in self.feeds], self.feeds, stale_after=stale_after, name="dash")


class ReplaySource(threading.Thread):
    """A thread replaying a session directory's devices with their recorded timing (the
    shared :func:`~bench.ingest.pacer.pace`); reads are stamped when delivered."""

    def __init__(self, directory: str | Path, feeds: list[DeviceFeed], speed: float = 1.0) -> None:
        super().__init__(name="dash-replay", daemon=True)
        self.directory = Path(directory)
        self.feeds = list(feeds)
        self._by_name = {f.spec.name: f for f in self.feeds}
        self.speed = speed
        self.stopping = threading.Event()  # not _stop: threading.Thread has one

    def request_stop(self) -> None:
        self.stopping.set()

    def _tick(self) -> None:
        mono, utc = time.monotonic(), time.time()
        for feed in self.feeds:
            read = feed.device.idle(mono, utc)
            if read.records:
                feed.on_read(feed.device, read)
            feed.on_tick(mono)

    def _deliver(self, name: str, raw: Read) -> None:
        feed = self._by_name[name]
        feed.on_read(feed.device, feed.device.ingest(raw.data, time.monotonic(), time.time()))

    def run(self) -> None:
        try:
            reads = load_reads(self.directory, self._by_name)  # checked whole first; replayed as a stream
        except InputError as exc:  # a log changed since the command line checked it
            reads = {}
            for feed in self.feeds:
                feed.set_state("down", str(exc))
        for name in reads:
            self._by_name[name].set_state("up")
        pace(reads, self._deliver, self.speed, self.stopping, tick=self._tick, tick_interval=READ_TIMEOUT)
        mono, utc = time.monotonic(), time.time()
        for feed in self.feeds:
            feed.on_read(feed.device, feed.device.stop(mono, utc))
            feed.stop()
            if not self.stopping.is_set():
                feed.set_state("ended", "end of the session")


def start_sources(config, post: Post) -> list:
    """Start the reader threads of ``config`` (a :class:`~bench.dash.app.DashConfig`) and
    return them: one :class:`ReplaySource` for a session directory, else one
    :class:`LiveSource` for every live device (with scene truth for an ``arvaemu://``
    receiver when asked)."""
    if config.replay is not None:
        # The links show where the bytes come from now: the session's raw logs.
        feeds = [DeviceFeed(replace(s, url=str(config.replay / f"{s.name}.raw")), post) for s in config.specs]
        sources = [ReplaySource(config.replay, feeds, config.replay_speed)]
    else:
        feeds = []
        for spec in config.specs:
            truth = SceneTruth.for_url(spec.url, spec.role) if config.scene_truth and spec.kind == "arva" else None
            feeds.append(DeviceFeed(spec, post, truth))
        sources = [LiveSource(feeds, config.stale_after)]  # one ingest loop reads them all
    for source in sources:
        source.start()
    return sources
