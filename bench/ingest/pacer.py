"""Replaying a session's reads with their recorded timing: the one pacer of ``arva-bench
replay`` (reads to ports) and ``arva-bench dash SESSION`` (reads to the dashboard).

Reads of every device are merged by the logger's monotonic clock (``mono``, s), so the
interleaving across devices is the one the logger saw, and delivered at
``start + (mono - mono_first) / speed`` on this process's monotonic clock (``speed`` 0:
as fast as possible).
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from emulator.cli_types import speed_value

from ..session import RawLog, Read, session_logs


def load_reads(directory: str | Path, names: Iterable[str]) -> dict[str, RawLog]:
    """The raw logs of the devices ``names`` of a session that logged something, each
    checked whole now (:meth:`RawLog.scan`: an :class:`InputError` naming the file and line
    before anything is replayed) and read again, as a stream, when replayed."""
    return {name: log.scan() for name, log in session_logs(directory, names).items()}


def pace(reads: dict[str, Iterable[Read]], deliver: Callable[[str, Read], None], speed: float = 1.0,
         stop: threading.Event | None = None, tick: Callable[[], None] | None = None,
         tick_interval: float = 0.1) -> int:  # fmt: skip
    """Deliver every read (``deliver(name, read)``) in the logger's order at its recorded
    pace, each device's reads taken one at a time from its iterable, until the end or
    ``stop``; returns how many were delivered. ``tick`` (optional) is called at least every
    ``tick_interval`` seconds while waiting for the next read (the dashboard uses it to
    release epochs of a quiet link). InputError for a bad ``speed``."""
    speed = speed_value(speed)  # the one speed rule (emulator.cli_types)
    stop = stop if stop is not None else threading.Event()
    start, t0, sent = time.monotonic(), None, 0
    streams = (zip(itertools.repeat(name), logged) for name, logged in reads.items())
    # One pending read per device in a heap; of equal stamps, the device listed first goes first.
    for name, read in heapq.merge(*streams, key=lambda item: item[1].mono):
        if stop.is_set():
            break
        t0 = read.mono if t0 is None else t0
        if speed > 0:
            due = start + (read.mono - t0) / speed
            delay = due - time.monotonic()
            while delay > 0:
                if stop.wait(delay if tick is None else min(delay, tick_interval)):
                    return sent
                if tick is not None:
                    tick()
                delay = due - time.monotonic()
        deliver(name, read)
        sent += 1
    return sent
