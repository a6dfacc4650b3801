"""The epoch scheduler: renders every stream's epochs at their deadlines and writes them.

Real time (``speed > 0``): epoch k of a stream is due at ``start + k / (rate_hz * speed)``
on the monotonic clock, rendered ahead of its deadline (docs/emulator.md, "Timing"). As
fast as possible (``speed == 0``): batches covering a window of scene time, stream by stream.

A live control channel (:mod:`emulator.control`) changes the scene between epochs: every
render and write here happens under :attr:`EpochScheduler.lock`, which the channel holds
while it applies a change (or steps the step clock, :meth:`emulator.pipeline.Pipeline.step`),
so a change takes effect from the next epoch rendered (:attr:`EpochScheduler.next_epoch`).
:attr:`EpochScheduler.paused` stops the real clock emitting: epochs keep their deadlines
and are rendered, then discarded, so a resume continues with the epoch due then and
replays nothing (as fast as possible, where nothing is ever due, pause just waits).
"""

from __future__ import annotations

import heapq
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from emulator.output.ports import Port
from emulator.output.streams import Stream

#: Epochs per batch of the fastest stream when running as fast as possible.
FAST_BATCH = 4096
#: Longest single sleep, so a stop request is noticed promptly.
MAX_SLEEP = 0.1
#: The last this-many seconds before a real-time deadline are spent spinning.
SPIN = 0.001
#: As fast as possible, a full port buffer may take this long to drain before bytes
#: are dropped: a reader that keeps up loses nothing, an absent one blocks nothing.
FAST_DRAIN_WAIT = 0.05
#: Under the step clock a reader may look idle this long before it is taken to be
#: absent: nothing is due in real time, and QEMU reading its UART's pty at ~15 KB/s
#: frees room only in large chunks, so a reader that keeps reading shows no progress
#: for 1-3 s now and then (tests/perf/bench_firmware_loop.py measures the longest).
#: A pty we created that nobody has read yet waits only ports.PTY_FIRST_WAIT.
STEP_DRAIN_WAIT = 5.0


class SceneClock:
    """Scene time (s) of the epoch being written; read by port wrappers (link faults).

    As fast as possible it advances per batch, so faults scheduled in scene time land on
    batch boundaries there; in real time it is exact to the epoch.
    """

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def epochs_before(first_epochs: int, rate_hz: float, first_rate_hz: float) -> int:
    """How many epochs of a stream at ``rate_hz`` come before the scene time that ends
    the first stream's ``first_epochs`` epochs: those with k / rate < first_epochs /
    first_rate (the ``--frames`` rule, used by every clock; 1e-9 guards float ratios)."""
    if rate_hz == first_rate_hz:
        return first_epochs
    return math.ceil(first_epochs * rate_hz / first_rate_hz - 1e-9)


@dataclass
class Route:
    """A stream bound to the port it is written to."""

    stream: Stream
    port: Port
    next_k: int = 0
    end_k: int | None = None
    pending: bytes | None = field(default=None, repr=False)

    @property
    def done(self) -> bool:
        return self.end_k is not None and self.next_k >= self.end_k

    @property
    def t_next(self) -> float:
        """Scene time (s) of the next epoch to write."""
        return self.next_k / self.stream.rate_hz

    def send(self, count: int, clock: SceneClock) -> None:
        """Render the next ``count`` epochs and write them, with ``clock`` at the scene
        time of what is written. One write for them all, or one per epoch when the port's
        faults depend on the scene time (outages): bytes are the same either way."""
        if count <= 0:
            return
        per_write = 1 if getattr(self.port, "time_dependent", False) else count
        for _ in range(count // per_write):
            clock.t = self.t_next
            self.port.write(self.stream.render(self.next_k, per_write))
            self.next_k += per_write


class EpochScheduler:
    """Runs routes until ``frames`` epochs of the first stream were sent, or :meth:`stop`.

    Other streams stop at the same scene time (epochs with t_k < frames / rate_0).
    ``clock`` and ``sleep`` are injectable for tests.
    """

    def __init__(self, routes: list[Route], speed: float, frames: int | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
                 status: Callable[[list[Route]], None] | None = None,
                 stop_event: threading.Event | None = None, scene_clock: SceneClock | None = None,
                 fast_batch: int | None = None,
                 on_write: Callable[[Route, int, float, float, float], None] | None = None) -> None:
        if not routes:
            raise ValueError("nothing to schedule")
        self.routes = routes
        self.speed = speed
        self.clock = clock
        self.sleep = sleep
        self.status = status
        self.scene_clock = scene_clock if scene_clock is not None else SceneClock()
        self.fast_batch = fast_batch
        #: Real clock only: called after each epoch's write with (route, epoch k, deadline,
        #: write start, write end), clock seconds (``--timing-log``); None costs nothing.
        self.on_write = on_write
        # An Event rather than a flag so a signal handler installed before the scheduler
        # exists (while ports are being opened) can already request the stop.
        self._stop = stop_event if stop_event is not None else threading.Event()
        #: Held while rendering and writing; a control channel holds it to change the scene.
        self.lock = threading.RLock()
        self.paused = False
        if frames is not None:
            rate0 = routes[0].stream.rate_hz
            for r in routes:
                r.end_k = epochs_before(frames, r.stream.rate_hz, rate0)

    def stop(self) -> None:
        """Ask the run to end after the current epoch (safe from a signal handler)."""
        self._stop.set()

    @property
    def next_epoch(self) -> int:
        """Index of the first stream's next epoch to be rendered: the first a change made
        now affects (in real time the next epoch due is already rendered)."""
        r = self.routes[0]
        return r.next_k + (1 if r.pending is not None else 0)

    def remaining(self) -> int | None:
        """Epochs of the first stream still to send under ``frames`` (None: no limit)."""
        r = self.routes[0]
        return None if r.end_k is None else max(0, r.end_k - r.next_k)

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` before the first epoch, interruptible by :meth:`stop`."""
        end = self.clock() + seconds
        while not self._stop.is_set() and (left := end - self.clock()) > 0:
            self.sleep(min(left, MAX_SLEEP))

    def run(self) -> None:
        if self.speed == 0:
            self._run_fast()
        else:
            self._run_real_time()

    def _write(self, route: Route, data: bytes) -> None:
        self.scene_clock.t = route.next_k / route.stream.rate_hz
        if not self.paused:  # paused: rendered, then discarded
            route.port.write(data)

    def _run_fast(self) -> None:
        for r in self.routes:
            r.port.set_drain_wait(FAST_DRAIN_WAIT)
        batch = self.fast_batch or FAST_BATCH
        window = batch / max(r.stream.rate_hz for r in self.routes)
        t_end = 0.0
        next_status = self.clock() + 0.5
        while not self._stop.is_set() and not all(r.done for r in self.routes):
            t_end += window
            while self.paused and not self._stop.is_set():  # nothing is due as fast as possible: wait
                self.sleep(0.01)
            with self.lock:
                for r in self.routes:
                    k_hi = math.ceil(t_end * r.stream.rate_hz)
                    if r.end_k is not None:
                        k_hi = min(k_hi, r.end_k)
                    r.send(k_hi - r.next_k, self.scene_clock)
            if self.status is not None and self.clock() >= next_status:
                self.status(self.routes)
                next_status += 0.5

    def _run_real_time(self) -> None:
        heap = []
        with self.lock:
            # Render every first epoch before the clock starts: the first render is the
            # slowest (cold caches, first use of the model's buffers), and epoch 0 is due
            # at the start, so rendering it after would make it late by that much.
            for r in self.routes:
                if not r.done:
                    r.pending = r.stream.render(r.next_k, 1)
            start = self.clock()
            due = lambda r: start + r.next_k / (r.stream.rate_hz * self.speed)  # noqa: E731
            for i, r in enumerate(self.routes):
                if not r.done:
                    heapq.heappush(heap, (due(r), i))
        next_status = start + 0.5
        while heap and not self._stop.is_set():
            deadline, i = heap[0]
            delay = deadline - self.clock()
            if delay > SPIN:
                # Sleep to just short of the deadline, then spin: sleep() wakes late
                # by up to a scheduler tick under load, a short spin does not.
                self.sleep(min(delay - SPIN, MAX_SLEEP))
                continue
            if delay > 0:
                continue  # spin
            heapq.heappop(heap)
            r = self.routes[i]
            with self.lock:
                if self.on_write is None:
                    self._write(r, r.pending)
                else:
                    t0 = self.clock()
                    self._write(r, r.pending)
                    self.on_write(r, r.next_k, deadline, t0, self.clock())
                r.next_k += 1
                r.pending = None
                if not r.done:
                    r.pending = r.stream.render(r.next_k, 1)  # ahead of its deadline
                    heapq.heappush(heap, (due(r), i))
            if self.status is not None and self.clock() >= next_status:
                self.status(self.routes)
                next_status = self.clock() + 0.5


def summary_line(routes: list[Route]) -> str:
    """``N epochs sent (arva N, gps:rx M), B bytes dropped, F faults injected``."""
    per = ", ".join(f"{r.stream.label} {r.next_k}" for r in routes)
    dropped = sum(r.port.bytes_dropped for r in routes)
    faults = sum(getattr(r.port, "faults_injected", 0) for r in routes)
    return f"{routes[0].next_k} epochs sent ({per}), {dropped} bytes dropped, {faults} faults injected"


def status_printer(stream=sys.stderr) -> Callable[[list[Route]], None]:
    """A live one-line status on a terminal (carriage return, no scrolling)."""

    def show(routes: list[Route]) -> None:
        stream.write("\r" + summary_line(routes) + "\x1b[K")
        stream.flush()

    return show
