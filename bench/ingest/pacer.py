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

from emulator.cli_types import speed_value

from ..session import RawLog, RawRead, session_logs


def load_reads(directory: str | Path, names: Iterable[str]) -> dict[str, RawLog]:
    """The raw logs of the devices ``names`` of a session that logged something, each
    checked whole now (:meth:`RawLog.scan`: an :class:`InputError` naming the file and line
    before anything is replayed) and read again, as a stream, when replayed."""
    return {name: log.scan() for name, log in session_logs(directory, names).items()}


class ReplayPacer:
    """Delivers reads in the logger's order at their recorded pace.

    ``tick`` (optional) is called at least every ``tick_interval`` seconds while waiting
    for the next read (the dashboard uses it to release epochs of a quiet link).
    """

    def __init__(self, reads: dict[str, Iterable[RawRead]], speed: float = 1.0, stop: threading.Event | None = None,
                 tick: Callable[[], None] | None = None, tick_interval: float = 0.1) -> None:  # fmt: skip
        self.reads = reads
        self.speed = speed_value(speed)  # InputError: the one speed rule (emulator.cli_types)
        self.stop = stop if stop is not None else threading.Event()
        self.tick = tick
        self.tick_interval = tick_interval
        self.sent = 0

    def run(self, deliver: Callable[[str, RawRead], None]) -> bool:
        """Deliver every read (``deliver(name, read)``); False if stopped before the end.
        Each device's reads are taken one at a time from its iterable."""
        streams = {name: iter(r) for name, r in self.reads.items()}
        queue = []
        for i, (name, it) in enumerate(streams.items()):
            first = next(it, None)
            if first is not None:
                queue.append((first.mono, i, name, first))
        heapq.heapify(queue)
        t0 = queue[0][0] if queue else 0.0
        start = time.monotonic()
        stop = self.stop
        while queue:
            if stop.is_set():
                return False
            mono, i, name, read = heapq.heappop(queue)
            if self.speed > 0:
                due = start + (mono - t0) / self.speed
                delay = due - time.monotonic()
                while delay > 0:
                    if stop.wait(delay if self.tick is None else min(delay, self.tick_interval)):
                        return False
                    if self.tick is not None:
                        self.tick()
                    delay = due - time.monotonic()
            deliver(name, read)
            self.sent += 1
            following = next(streams[name], None)
            if following is not None:
                heapq.heappush(queue, (following.mono, i, name, following))
        return not stop.is_set()
