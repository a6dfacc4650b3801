"""The dashboard's state, fed by the messages and read by the widgets (no textual here).

* :class:`ReceiverState`: the latest epoch of a receiver and the d history per transmitter.
* :class:`TruthState`: ground truth per role (``rx``, ``rx<N>``, ``tx<ID>``): the last GPS
  fix mapped to ENU, the last attitude, surveyed transmitter poses, or poses straight from
  an emulated scene; the true distance receiver-transmitter where both are known.
* :class:`LinkView`: one device link's counters, state, record rate and data age.

ENU origin for GPS fixes (as ``arva-bench export``): ``--origin``, else the session's,
else the first valid receiver fix.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from emulator.frames.attitude import hpr_to_quaternion, quaternion_to_hpr
from emulator.frames.geodesy import Origin, geodetic_to_enu

from .messages import LinkCounters

#: Epochs of d history kept per receiver (the sparklines show the newest that fit).
HISTORY = 120
#: Record rate: arrivals within this many seconds of now.
RATE_WINDOW = 10.0

Slot = tuple[int, int, int]


@dataclass
class ReceiverState:
    device: str
    role: str
    seq: int | None = None
    slots: list[Slot | None] = field(default_factory=list)
    complete: bool = True
    epochs: int = 0
    history: deque = field(default_factory=lambda: deque(maxlen=HISTORY))

    def on_epoch(self, seq: int, slots: list[Slot | None], complete: bool = True) -> None:
        self.seq = seq
        self.slots = list(slots)
        self.complete = complete
        self.epochs += 1
        self.history.append({s[0]: s[1] for s in slots if s is not None and s[0] >= 0 and s[1] >= 0})

    def histories(self) -> dict[int, list[int | None]]:
        """d (cm) of each slot's transmitter in each kept epoch, None where it was not received."""
        return {s[0]: [h.get(s[0]) for h in self.history] for s in self.slots if s is not None and s[0] >= 0}


@dataclass
class Pose:
    """What is known of one role; any part may be missing."""

    position: tuple[float, float, float] | None = None  # ENU metres
    q: tuple[float, float, float, float] | None = None
    hpr: tuple[float, float, float] | None = None  # heading, roll, pitch (degrees)
    via: str = ""  # gps, surveyed, scene
    fix: dict | None = None  # the last GGA (else RMC) record
    geodetic: tuple[float, float, float] | None = None  # lat, lon, alt (HAE)


def role_key(role: str) -> tuple[int, int, str]:
    """Receivers first, then transmitters by id."""
    kind = 0 if role.startswith("rx") else 1
    num = role[2:]
    return kind, int(num) if num.isdigit() else -1, role


class TruthState:
    def __init__(self, origin: Origin | None = None, tx_poses: dict[int, list[float]] | None = None) -> None:
        self.origin = origin
        self.poses: dict[str, Pose] = {}
        self._surveyed = dict(tx_poses or {})
        self._place_surveyed()

    def _place_surveyed(self) -> None:
        for tx, values in self._surveyed.items():
            pose = self.poses.setdefault(f"tx{tx}", Pose())
            lat, lon, alt, *hrp = values
            pose.geodetic = (lat, lon, alt)
            pose.via = "surveyed"
            if hrp:  # heading[, roll[, pitch]]: the missing ones 0
                pose.hpr = tuple((hrp + [0.0, 0.0])[:3])
                pose.q = tuple(float(v) for v in hpr_to_quaternion(*pose.hpr))
            if self.origin is not None:
                pose.position = self._enu(lat, lon, alt)

    def _enu(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        e, n, u = geodetic_to_enu(lat, lon, alt, self.origin)
        return float(e), float(n), float(u)

    # -- inputs ----------------------------------------------------------------------
    def on_fix(self, role: str, fix: dict) -> None:
        pose = self.poses.setdefault(role, Pose())
        if fix.get("sentence") == "GGA" or pose.fix is None or pose.fix.get("sentence") != "GGA":
            pose.fix = fix
        pose.via = "gps"
        if fix.get("sentence") != "GGA" or not fix.get("valid") or fix.get("lat") is None:
            return  # positions come from GGA: it has the altitude
        alt = fix.get("alt_hae")
        if alt is None:
            alt = fix.get("alt_msl") or 0.0
        pose.geodetic = (fix["lat"], fix["lon"], alt)
        if self.origin is None and role.startswith("rx"):
            self.origin = Origin(fix["lat"], fix["lon"], alt)
            self._place_surveyed()
            for other in self.poses.values():  # fixes seen before the origin was known
                if other.position is None and other.geodetic is not None:
                    other.position = self._enu(*other.geodetic)
        if self.origin is not None:
            pose.position = self._enu(*pose.geodetic)

    # The messages (bench.dash.messages) hand positions and quaternions over as float tuples.
    def on_attitude(self, role: str, heading: float, roll: float, pitch: float, q: tuple[float, ...]) -> None:
        pose = self.poses.setdefault(role, Pose())
        pose.hpr = (heading, roll, pitch)
        pose.q = q

    def on_pose(self, role: str, position: tuple[float, float, float], q: tuple[float, ...] | None, via: str) -> None:
        pose = self.poses.setdefault(role, Pose())
        pose.position = position
        pose.via = via
        if q is not None:
            pose.q = q
            h, r, p = quaternion_to_hpr(q)
            pose.hpr = (float(h), float(r), float(p))

    # -- outputs ---------------------------------------------------------------------
    def distances(self, rx_role: str, ids) -> dict[int, float]:
        """True distances (m) from ``rx_role`` to the transmitters ``ids`` where both are placed."""
        rx = self.poses.get(rx_role, Pose()).position
        placed = {tx: p for tx in ids if (p := self.poses.get(f"tx{tx}", Pose()).position) is not None}
        return {} if rx is None else {tx: math.dist(rx, p) for tx, p in placed.items()}

    def roles(self) -> list[str]:
        return sorted(self.poses, key=role_key)


@dataclass
class LinkView:
    device: str
    kind: str = "arva"
    role: str = "rx"
    url: str = ""
    state: str = "connecting"
    reason: str = ""
    counters: LinkCounters = field(default_factory=LinkCounters)
    state_since: float | None = None
    arrivals: deque = field(default_factory=lambda: deque(maxlen=256))
    seen_gga: bool = False

    def arrived(self, mono: float, count: int | None = None) -> None:
        """A record at ``mono``; ``count`` is the source's running record count (None: one more)."""
        if count is None:
            count = self.arrivals[-1][1] + 1 if self.arrivals else 1
        self.arrivals.append((mono, count))

    def age(self, now: float) -> float | None:
        """Seconds since the last data (a record, or bytes the counters saw), or None."""
        last = self.counters.last_data_mono
        if self.arrivals and (last is None or self.arrivals[-1][0] > last):
            last = self.arrivals[-1][0]
        return None if last is None else max(0.0, now - last)

    def stale(self, now: float, after: float) -> bool:
        """Up (or waiting for its first byte) but silent for more than ``after`` s."""
        if self.state == "ended":
            return False
        age = self.age(now)
        if age is not None:
            return age > after
        return self.state == "up" and self.state_since is not None and now - self.state_since > after

    def rate(self, now: float, stale_after: float) -> float | None:
        """Records per second over the last :data:`RATE_WINDOW` s; 0 when stale or over."""
        age = self.age(now)
        if self.stale(now, stale_after) or (self.state == "ended" and age is not None and age > stale_after):
            return 0.0
        recent = [(t, c) for t, c in self.arrivals if now - t <= RATE_WINDOW]
        if len(recent) < 2 or recent[-1][0] <= recent[0][0]:
            return None
        return (recent[-1][1] - recent[0][1]) / (recent[-1][0] - recent[0][0])
