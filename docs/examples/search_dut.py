"""A small device under test: the search logic of a drone that carries an ARVA receiver.

It reads the receiver's serial port (``$PARVA`` sentences, docs/protocol.md), runs a
search state machine and prints one JSON line per epoch on stdout::

    {"seq": 12, "state": "coarse", "target": 1, "d": 1905}

States: ``no_signal`` (no target), ``coarse`` (target farther than 10 m), ``fine``
(within 10 m), ``located`` (within 3 m, the receiver's inner zone). The first
transmitter heard becomes the target and stays the target while it is heard, even when a
closer one appears; after ``LOST_AFTER`` epochs without it the search starts again. A
cable pulled out (the port vanishes) is survived: the program reopens the port (the
same path, e.g. a stable symlink) every 0.1 s, prints ``{"event": "link_lost"}`` and
``{"event": "link_back"}``, and keeps its state.

Run: ``python search_dut.py /dev/ttyUSB0`` (stops on SIGTERM / Ctrl-C). Only pyserial.
"""

from __future__ import annotations

import json
import signal
import sys
import time
from functools import reduce

import serial

FINE_CM = 1000
LOCATED_CM = 300
LOST_AFTER = 3


def parse_parva(line: bytes):
    """(seq, n, k, id, d, delta) of a valid $PARVA sentence, else None."""
    line = line.strip()
    if not line.startswith(b"$PARVA,") or b"*" not in line:
        return None
    body, _, check = line[1:].partition(b"*")
    try:
        if int(check, 16) != reduce(lambda a, b: a ^ b, body, 0):
            return None
        fields = [int(f) for f in body.split(b",")[1:]]
    except ValueError:
        return None
    return tuple(fields) if len(fields) == 6 else None


class Search:
    """The state machine; :meth:`epoch` takes one epoch's slots [(id, d, delta), ...]."""

    def __init__(self) -> None:
        self.target: int | None = None
        self.missed = 0
        self.d = -1

    @property
    def state(self) -> str:
        if self.target is None:
            return "no_signal"
        if self.d <= LOCATED_CM:
            return "located"
        return "fine" if self.d <= FINE_CM else "coarse"

    def epoch(self, slots: list[tuple[int, int, int]]) -> None:
        heard = {tx_id: d for tx_id, d, _ in slots if tx_id >= 0 and d >= 0}
        if self.target is not None and self.target in heard:
            self.missed, self.d = 0, heard[self.target]
        elif self.target is not None:
            self.missed += 1
            if self.missed >= LOST_AFTER:
                self.target, self.d = None, -1
        if self.target is None and heard:
            self.target = min(heard, key=lambda i: (heard[i], i))  # the nearest first
            self.d, self.missed = heard[self.target], 0


class Epochs:
    """Assembles epochs from single $PARVA sentences: :meth:`feed` takes one sentence's
    fields and returns (seq, slots) when it completes an epoch (k = n) whose first slot
    (k = 1) was seen with the same seq, else None."""

    def __init__(self) -> None:
        self.slots: list[tuple[int, int, int]] = []
        self.seq: int | None = None

    def reset(self) -> None:
        self.slots = []

    def feed(self, fields) -> tuple[int, list[tuple[int, int, int]]] | None:
        s, n, k, tx_id, d, delta = fields
        if k == 1:
            self.slots, self.seq = [], s
        if s != self.seq:
            return None  # a slot of an epoch whose start we missed
        self.slots.append((tx_id, d, delta))
        return (self.seq, self.slots) if k == n else None


def run(path: str) -> None:
    search = Search()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    say = lambda obj: print(json.dumps(obj), flush=True)  # noqa: E731
    port = None
    epochs = Epochs()
    while not stop:
        if port is None:
            try:
                port = serial.Serial(path, timeout=0.1)
                if epochs.seq is not None:
                    say({"event": "link_back"})
            except (serial.SerialException, OSError):
                time.sleep(0.1)
                continue
        try:
            line = port.readline()
        except (serial.SerialException, OSError):
            port.close()
            port = None
            epochs.reset()
            say({"event": "link_lost"})
            continue
        fields = parse_parva(line)
        done = epochs.feed(fields) if fields is not None else None
        if done is not None:
            seq, slots = done
            search.epoch(slots)
            say({"seq": seq, "state": search.state, "target": search.target, "d": search.d})


if __name__ == "__main__":
    try:
        run(sys.argv[1])
    except KeyboardInterrupt:
        pass
