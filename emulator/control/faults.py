"""Faults asked for over the control channel (BRIEF 9 ``fault``), on one stream's port.

:class:`ControlledPort` wraps a stream's port (after the scene's own ``link_faults``) and
is one itself. Times are scene times, read from the scheduler's scene clock at each
write, so under the step clock a fault's seconds and milliseconds are scene time and in
real time they follow the scene clock (``--speed`` times the wall clock). A fault starts
at the stream's next write (the next epoch rendered):

* ``disconnect`` (``seconds``): the port vanishes as a ``link_faults`` outage does (a pty
  is closed, and re-created with a new path when the outage is over, announced again and
  followed by the ``--link`` symlink; a port that cannot disconnect drops the bytes).
  Epochs written at scene times in [t0, t0 + seconds) are lost; the port comes back at
  the first write at or after t0 + seconds.
* ``stall`` (``ms``): the stream's bytes are held back from t0 until scene time
  t0 + ms / 1000 and go out, in order, with the first write at or after it (at epoch
  granularity: nothing is written between epochs). At most :data:`MAX_HELD` bytes are
  held; beyond that they are dropped and counted, as a UART's FIFO overflows.
* ``corrupt`` (``count``): the next ``count`` bytes written are each XOR-ed with
  :data:`CORRUPT_XOR` (so each one changes, and a decoder sees bad checksums).

With ``--capture DIR`` every byte handed to the port (after these faults, before the
scene's ``link_faults`` and before a full buffer drops any) is also appended to
``DIR/<stream>.bytes`` (``:`` in a label becomes ``-``), unbuffered, so a test harness
can save what a device under test was sent.

Nothing is wrapped without ``--control``, so without a control channel this costs nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import BinaryIO

from firmware_proto.errors import LinkError

from emulator.output.ports import Port

#: Most bytes a stall holds back (a UART FIFO plus a driver buffer, generously).
MAX_HELD = 65536
#: Every corrupted byte is XOR-ed with this (never 0, so the byte always changes).
CORRUPT_XOR = 0x55


class ControlledPort(Port):
    """A port that takes faults from the control channel (see the module docstring)."""

    def __init__(self, port: Port, clock: Callable[[], float], capture: BinaryIO | None = None) -> None:
        super().__init__(port.label)
        self.inner = port
        #: Receives a copy of every byte handed to the port (``--capture``).
        self.capture = capture
        self._clock = clock
        self._disconnect_s: float | None = None  # asked for, starts at the next write
        self._down_until: float | None = None
        self._down_simulated = False
        self._stall_s: float | None = None
        self._held_until: float | None = None
        self._held = bytearray()
        self._corrupt_left = 0
        self.faults_requested = 0
        self.bytes_corrupted = 0
        self.bytes_disconnected = 0

    @property
    def path(self) -> str | None:  # type: ignore[override]
        return self.inner.path

    @property
    def faults_injected(self) -> int:
        return self.faults_requested + getattr(self.inner, "faults_injected", 0)

    @property
    def disconnected(self) -> bool:
        return self._down_until is not None

    def disconnect_for(self, seconds: float) -> None:
        self.faults_requested += 1
        self._disconnect_s = seconds

    def stall_for(self, ms: float) -> None:
        self.faults_requested += 1
        self._stall_s = ms / 1000.0

    def corrupt_next(self, count: int) -> None:
        self.faults_requested += 1
        self._corrupt_left += count

    def write(self, data: bytes) -> int:
        n = len(data)
        t = self._clock()
        if self._down_until is not None and t >= self._down_until:
            self._up()
        if self._disconnect_s is not None:
            seconds, self._disconnect_s = self._disconnect_s, None
            if self._down_until is None:
                self._go_down()
            self._down_until = max(self._down_until or 0.0, t + seconds)
        if self._down_until is not None:
            self.bytes_disconnected += n
            return self._account(n, 0)
        if self._stall_s is not None:
            self._held_until = max(self._held_until or t, t + self._stall_s)
            self._stall_s = None
        if self._held_until is not None:
            if t < self._held_until:
                room = MAX_HELD - len(self._held)
                self._held += data[:room]
                self.bytes_dropped += max(0, n - room)
                return 0  # accounted when released
            data, held = bytes(self._held) + data, len(self._held)
            self._held.clear()
            self._held_until = None
            n += held
        if self._corrupt_left:
            data = self._corrupt(data)
        if self.capture is not None:
            self.capture.write(data)
        return self._account(n, self.inner.write(data))

    def _corrupt(self, data: bytes) -> bytes:
        k = min(self._corrupt_left, len(data))
        self._corrupt_left -= k
        self.bytes_corrupted += k
        return bytes(b ^ CORRUPT_XOR for b in data[:k]) + data[k:]

    def _go_down(self) -> None:
        try:
            self.inner.disconnect()
            self._down_simulated = False
        except LinkError:
            self._down_simulated = True  # stdout, a URL: drop the bytes, close nothing

    def _up(self) -> None:
        self._down_until = None
        if not self._down_simulated:
            self.inner.reconnect()

    def set_drain_wait(self, seconds: float) -> None:
        self.inner.set_drain_wait(seconds)

    def disconnect(self) -> None:
        self.inner.disconnect()

    def reconnect(self) -> None:
        self.inner.reconnect()

    def close(self, *args, **kwargs) -> None:
        self.inner.close(*args, **kwargs)
        if self.capture is not None:
            self.capture.close()

    def __getattr__(self, name: str):
        # pending(), link, counters of the wrapped port read through.
        if name.startswith("_") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
