"""Link faults on a port (BRIEF 3.1 ``link_faults``; docs/emulator.md, "link_faults").

:class:`FaultyPort` wraps any :class:`~emulator.output.ports.Port` and is one itself. Per
write, in this order:

1. Disconnect schedule: outages from scene times k * ``disconnect_every_s`` (k >= 1),
   ``disconnect_s`` long. The wrapped port is ``disconnect()``-ed at the first write (or
   :meth:`FaultyPort.poll`) inside an outage and ``reconnect()``-ed at the first after
   it; an outage no write fell into is still applied (disconnect, then reconnect at
   once). Meanwhile bytes are dropped (``bytes_disconnected``) and nothing is drawn; a
   port that cannot disconnect (stdout) gets a simulated outage.
2. Stall: with probability ``stall``, ``sleep(stall_ms / 1000)`` before the write.
3. Bytes: each byte lost with probability ``loss``; each byte kept corrupted with
   probability ``corrupt`` (XOR with a uniform non-zero byte, so it always changes).
4. Split: with probability ``split`` into 2, 3 or 4 pieces (cut points uniform among
   the distinct positions), ``sleep(SPLIT_GAP_S)`` between them.

:meth:`FaultyPort.inject` adds faults on demand (the control channel). Time comes from
two injected callables, ``clock()`` (scene seconds) and ``sleep(seconds)`` (a no-op at
``--speed 0``), so the port never sleeps when running as fast as possible.

Determinism: stalls, byte faults, corruption values and splits each draw from their own
generator (from the seed and ``stream``), only when enabled. Byte faults draw one
fixed-size block per byte in stream order, so the faulted bytes do not depend on how the
stream is cut into writes (``--speed 0`` and real time carry the same), nor on splits or
stalls being on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_proto.errors import InputError, LinkError

from emulator.output.ports import Port, PortWrapper
from emulator.schema import is_number

#: Most bytes a held stall keeps (a UART FIFO plus a driver buffer, generously).
MAX_HELD = 65536
#: Pause between the pieces of a split write, seconds.
SPLIT_GAP_S = 0.001
#: Spawn-key tag of this effect's random streams ("LINK"), distinct from every other effect.
_TAG = 0x4C494E4B
_STALL, _BYTES, _SPLIT, _XOR, _FORCED = 0, 1, 2, 3, 4
#: Kinds of fault :meth:`FaultyPort.inject` applies, with the unit of their amount.
INJECTABLE = {"disconnect": "seconds", "stall": "ms", "corrupt": "bytes"}
#: The counters of :meth:`FaultyPort.summary`, in order.
COUNTERS = ("bytes_offered", "bytes_written", "bytes_dropped", "bytes_lost", "bytes_corrupted", "bytes_disconnected",
            "writes", "writes_split", "stalls", "disconnects")


@dataclass(frozen=True)
class LinkFaultConfig:
    """Scene settings of the ``link_faults`` effect (docs/emulator.md, "link_faults"):
    probabilities per byte (``loss``, ``corrupt`` of the bytes kept) or per write
    (``split``, ``stall``), ``stall_ms`` in ms, the outage period and length in scene
    seconds (``disconnect_every_s`` 0: never)."""

    loss: float = 0.0
    corrupt: float = 0.0
    split: float = 0.0
    stall: float = 0.0
    stall_ms: float = 200.0
    disconnect_every_s: float = 0.0
    disconnect_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("loss", "corrupt", "split", "stall"):
            v = getattr(self, name)
            if not is_number(v) or not 0 <= v <= 1:
                raise InputError(f"link_faults.{name}: must be a probability in [0, 1], got {v!r}")
        for name, positive, rule in (("stall_ms", False, ">= 0"),
                                     ("disconnect_every_s", False, ">= 0 (0 = never)"),
                                     ("disconnect_s", True, "> 0")):
            v = getattr(self, name)
            if not is_number(v) or v < 0 or (positive and v == 0):
                raise InputError(f"link_faults.{name}: must be {rule}, got {v!r}")
        if self.disconnect_every_s > 0 and self.disconnect_s >= self.disconnect_every_s:
            raise InputError(f"link_faults.disconnect_s: must be < disconnect_every_s "
                             f"({self.disconnect_every_s:g}), got {self.disconnect_s:g}")


class FaultyPort(PortWrapper):
    """A port that injects link faults into another port's stream (BRIEF 3.1).

    Cost per write: with byte faults on, 1 or 2 uniform draws per byte plus a few numpy
    operations on the byte array; splits, stalls and the disconnect schedule cost O(1)
    per write. Nothing is drawn for a fault whose probability is 0. Measured: ~20 us per
    small write (numpy call overhead), ~1 us per 81-byte epoch in 4096-epoch writes.

    Counters (also in :meth:`summary`): ``bytes_offered`` = ``bytes_written`` +
    ``bytes_dropped``; ``bytes_dropped`` = ``bytes_lost`` + ``bytes_disconnected`` + what
    the wrapped port itself dropped; ``bytes_corrupted``, ``writes``, ``writes_split``,
    ``stalls``, ``disconnects``; ``faults_injected`` sums the injected faults.
    """

    def __init__(self, port: Port, config: LinkFaultConfig, seed: int, stream: int = 0,
                 sleep: Callable[[float], None] = time.sleep, *, clock: Callable[[], float]) -> None:
        super().__init__(port)
        self.config = config
        self._sleep = sleep
        self._clock = clock
        rng = lambda part: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_TAG, stream, part)))  # noqa: E731
        self._rng_stall = rng(_STALL) if config.stall > 0 else None
        self._rng_bytes = rng(_BYTES) if config.loss > 0 or config.corrupt > 0 else None
        self._rng_split = rng(_SPLIT) if config.split > 0 else None
        self._rng_xor = rng(_XOR) if config.corrupt > 0 else None
        self._rng_forced = rng(_FORCED)  # the values of corrupt requests (inject)
        self._window = 0  # last outage index started
        self._down = False  # inside a scheduled outage
        self._manual_until: float | None = None  # end (scene time) of an outage asked for
        self._inner_down = False
        self._down_simulated = False
        self._stall_once_ms: float | None = None
        #: How a stall asked for is served: False sleeps (real time), True holds the
        #: bytes until the scene clock has advanced by the stall (the step clock, where
        #: nothing is written between steps and a stall is scene time).
        self.stall_hold = False
        self._held_until: float | None = None
        self._held = bytearray()
        self._corrupt_next = 0
        self.bytes_offered = 0
        self.bytes_lost = 0
        self.bytes_corrupted = 0
        self.bytes_disconnected = 0
        self.writes = 0
        self.writes_split = 0
        self.stalls = 0
        self.disconnects = 0

    @property
    def disconnected(self) -> bool:
        """True during an outage (scheduled or asked for)."""
        return self._down or self._manual_until is not None

    @property
    def time_dependent(self) -> bool:
        """True when what a write suffers depends on the scene time it is written at (an
        outage schedule, or an outage asked for): write such a port one epoch at a time."""
        return (
            self.config.disconnect_every_s > 0
            or self._manual_until is not None
            or self._held_until is not None
            or (self.stall_hold and self._stall_once_ms is not None)
        )

    def inject(self, kind: str, amount: float) -> None:
        """A fault on demand: ``disconnect`` for ``amount`` scene seconds from now,
        ``stall`` of ``amount`` ms before the next write, ``corrupt`` the next
        ``amount`` bytes written. Raises :class:`InputError` for anything else."""
        if kind not in INJECTABLE:
            raise InputError(f"fault kind {kind!r}: expected one of {', '.join(INJECTABLE)}")
        unit = INJECTABLE[kind]
        if not is_number(amount) or amount <= 0 or (kind == "corrupt" and int(amount) != amount):
            what = "a whole number > 0" if kind == "corrupt" else "a finite number > 0"
            raise InputError(f"fault {kind}: {unit} must be {what}, got {amount!r}")
        if kind == "disconnect":
            end = self._clock() + float(amount)
            self._manual_until = end if self._manual_until is None else max(end, self._manual_until)
            self.disconnects += 1
            self._inner_state()
        elif kind == "stall":
            self._stall_once_ms = float(amount)
        else:
            self._corrupt_next += int(amount)

    @property
    def faults_injected(self) -> int:
        return self.bytes_lost + self.bytes_corrupted + self.writes_split + self.stalls + self.disconnects

    def summary(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in COUNTERS}

    # --- Port interface ------------------------------------------------------------------

    def write(self, data: bytes) -> int:
        """Write ``data`` with faults; return the bytes the wrapped port accepted."""
        n = len(data)
        self.bytes_offered += n
        self.writes += 1
        self.poll()
        if self.disconnected:
            self.bytes_disconnected += n
            return self._account(n, 0)
        cfg = self.config
        if self._rng_stall is not None and self._rng_stall.random() < cfg.stall:
            self.stalls += 1
            self._sleep(cfg.stall_ms / 1000.0)
        if self._stall_once_ms is not None:
            self.stalls += 1
            if self.stall_hold:
                self._held_until = self._clock() + self._stall_once_ms / 1000.0
            else:
                self._sleep(self._stall_once_ms / 1000.0)
            self._stall_once_ms = None
        if self._held_until is not None:
            if self._clock() < self._held_until:
                room = max(0, MAX_HELD - len(self._held))
                self._held += data[:room]
                self.bytes_dropped += max(0, n - room)  # a full FIFO loses the rest
                return 0  # accounted for when released
            data, held = bytes(self._held) + data, len(self._held)
            self._held.clear()
            self._held_until = None
            n += held
        payload = self._fault_bytes(data)
        if self._corrupt_next and payload:
            payload = self._corrupt_forced(payload)
        accepted = 0
        for i, piece in enumerate(self._split(payload)):
            if i:
                self._sleep(SPLIT_GAP_S)
            accepted += self.inner.write(piece)
        return self._account(n, accepted)

    def poll(self) -> None:
        """Apply the disconnect schedule at the current scene time without writing (a
        scheduler may call it between writes so an outage ends on time)."""
        if self._manual_until is not None and self._clock() >= self._manual_until:
            self._manual_until = None
            self._inner_state()
        every = self.config.disconnect_every_s
        if every <= 0:
            return
        t = self._clock()
        k = math.floor(t / every)
        if self._down and (k > self._window or t >= self._window * every + self.config.disconnect_s):
            self._up()
        if k >= 1 and k > self._window:
            self._window = k
            self.disconnects += 1
            self._down = True
            self._inner_state()
            if t >= k * every + self.config.disconnect_s:  # the whole outage fell between writes
                self._up()

    # --- faults --------------------------------------------------------------------------

    def _up(self) -> None:
        self._down = False
        self._inner_state()

    def _inner_state(self) -> None:
        """Unplug the wrapped port while any outage lasts, plug it back after the last."""
        want_down = self.disconnected
        if want_down and not self._inner_down:
            self._inner_down = True
            try:
                self.inner.disconnect()
                self._down_simulated = False
            except LinkError:
                self._down_simulated = True  # e.g. stdout: drop bytes, close nothing
        elif not want_down and self._inner_down:
            self._inner_down = False
            if not self._down_simulated:
                self.inner.reconnect()

    def _corrupt_forced(self, payload: bytes) -> bytes:
        n = min(self._corrupt_next, len(payload))
        arr = np.frombuffer(payload, dtype=np.uint8).copy()
        arr[:n] ^= 1 + np.floor(self._rng_forced.random(n) * 255.0).astype(np.uint8)
        self._corrupt_next -= n
        self.bytes_corrupted += n
        return arr.tobytes()

    def _fault_bytes(self, data: bytes) -> bytes:
        rng = self._rng_bytes
        n = len(data)
        if rng is None or n == 0:
            return bytes(data)
        cfg = self.config
        arr = np.frombuffer(data, dtype=np.uint8)
        both = cfg.loss > 0 and cfg.corrupt > 0
        u = rng.random((n, 2) if both else n)
        keep = None
        if cfg.loss > 0:
            keep = (u[:, 0] if both else u) >= cfg.loss
        if cfg.corrupt > 0:
            hit = (u[:, 1] if both else u) < cfg.corrupt
            if keep is not None:
                hit &= keep
            n_hit = int(np.count_nonzero(hit))
            if n_hit:
                arr = arr.copy()
                # From doubles (one 64-bit draw each): numpy's uint8 integers() draw from a
                # 32-bit buffer discarded at the end of each call, which would make the
                # values depend on how the stream is cut into writes.
                xor = 1 + np.floor(self._rng_xor.random(n_hit) * 255.0).astype(np.uint8)
                arr[hit] ^= xor
                self.bytes_corrupted += n_hit
        if keep is not None:
            arr = arr[keep]
            self.bytes_lost += n - arr.size
        return arr.tobytes()

    def _split(self, payload: bytes) -> list[bytes]:
        rng = self._rng_split
        if rng is None or rng.random() >= self.config.split or len(payload) < 2:
            return [payload]
        pieces = min(int(rng.integers(2, 5)), len(payload))
        cuts = np.sort(rng.choice(len(payload) - 1, size=pieces - 1, replace=False) + 1).tolist()
        self.writes_split += 1
        bounds = [0, *cuts, len(payload)]
        return [payload[a:b] for a, b in zip(bounds, bounds[1:])]
