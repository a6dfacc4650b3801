"""Replaying a session's reads with their recorded timing: the one pacer of ``arva-bench
replay`` (reads to ports) and ``arva-bench dash SESSION`` (reads to the dashboard).

Reads of every device are merged by the logger's monotonic clock (``mono``, s), so the
interleaving across devices is the one the logger saw, and delivered at
``start + (mono - mono_first) / speed`` on this process's monotonic clock (``speed`` 0:
as fast as possible).
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from firmware_proto.errors import InputError

from ..session import RawRead, read_raw


def load_reads(directory: str | Path, names: Iterable[str]) -> dict[str, list[RawRead]]:
    """The reads of each device ``<name>.raw`` of a session (:class:`InputError` naming the
    file when one cannot be read)."""
    directory = Path(directory)
    return {name: read_raw(directory / f"{name}.raw").reads for name in names}


def check_speed(speed: float, command: str) -> None:
    if not (0 <= speed < float("inf")):
        raise InputError(f"{command}: --speed {speed}: must be a finite number >= 0")


class ReplayPacer:
    """Delivers reads in the logger's order at their recorded pace.

    ``tick`` (optional) is called at least every ``tick_interval`` seconds while waiting
    for the next read (the dashboard uses it to release epochs of a quiet link).
    """

    def __init__(self, reads: dict[str, list[RawRead]], speed: float = 1.0, stop: threading.Event | None = None,
                 tick: Callable[[], None] | None = None, tick_interval: float = 0.1) -> None:  # fmt: skip
        self.reads = reads
        self.speed = speed
        self.stop = stop if stop is not None else threading.Event()
        self.tick = tick
        self.tick_interval = tick_interval
        self.sent = 0

    def run(self, deliver: Callable[[str, RawRead], None]) -> bool:
        """Deliver every read (``deliver(name, read)``); False if stopped before the end."""
        reads = self.reads
        queue = [(r[0].mono, i, n, 0) for i, (n, r) in enumerate(reads.items()) if r]
        heapq.heapify(queue)
        t0 = queue[0][0] if queue else 0.0
        start = time.monotonic()
        stop = self.stop
        while queue:
            if stop.is_set():
                return False
            mono, i, name, j = heapq.heappop(queue)
            if self.speed > 0:
                due = start + (mono - t0) / self.speed
                delay = due - time.monotonic()
                while delay > 0:
                    if stop.wait(delay if self.tick is None else min(delay, self.tick_interval)):
                        return False
                    if self.tick is not None:
                        self.tick()
                    delay = due - time.monotonic()
            deliver(name, reads[name][j])
            self.sent += 1
            if j + 1 < len(reads[name]):
                heapq.heappush(queue, (reads[name][j + 1].mono, i, name, j + 1))
        return not stop.is_set()
