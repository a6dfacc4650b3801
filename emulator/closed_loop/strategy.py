"""What every search strategy shares (emulator.closed_loop.controllers has the overview):
the observation a controller sees per control tick, epochs and controller state as numpy
arrays over B runs, the exact element-wise ``math`` functions, the phases, the tick plan a
batch loop replays, the lawnmower signal search and the :class:`Controller` base class.
Positions ENU metres, yaw radians (0 = east, counter-clockwise), d centimetres, delta degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from emulator.closed_loop.vehicle import VehicleSpec

#: Inner zone: d <= this many centimetres (BRIEF 3: r_inner = 3 m) and delta = 0.
INNER_CM = 300


@dataclass
class Observation:
    t: float
    x: float
    y: float
    z: float
    yaw: float  # rad, ENU (0 = east, counter-clockwise)
    height: float  # range sensor y_s, metres above the terrain (noisy)
    ids: list[int]
    d: list[int]  # cm, -1 = none
    delta: list[int]  # deg
    field: list[list[float]] | None  # receiver-frame field per slot (scene units)
    new_epoch: bool


@dataclass
class EpochArrays:
    """One receiver epoch for B controllers at once (the array form of the epoch part of
    :class:`Observation`; a per-run controller uses B = 1): positions and yaws (B,),
    slots (B, C), the receiver-frame field (B, C, 3) or None, and ``marked`` (B, C):
    whether the slot's id is one this run has marked already."""

    t: float
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    ids: np.ndarray
    d: np.ndarray
    delta: np.ndarray
    field: np.ndarray | None
    marked: np.ndarray

    @classmethod
    def of(cls, obs: Observation, marked: set[int]) -> "EpochArrays":
        """A batch of one: ``obs`` of a run that has marked ``marked``."""
        fld = None if obs.field is None else np.array([obs.field], dtype=np.float64)
        return cls(obs.t, np.array([obs.x]), np.array([obs.y]), np.array([obs.yaw]), np.array([obs.ids]),
                   np.array([obs.d]), np.array([obs.delta]), fld, np.array([[i in marked for i in obs.ids]]))


class StateArrays:
    """Controller state (or constants) as numpy arrays, one element per run: a dataclass
    of arrays whose rows can be taken out (:meth:`take`) and put back (:meth:`put`)."""

    @classmethod
    def empty(cls, n: int):
        return cls(**{f.name: np.full(n, f.default, dtype=type(f.default)) for f in fields(cls)})

    def take(self, rows: np.ndarray):
        return type(self)(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    def put(self, rows: np.ndarray, part) -> None:
        for f in fields(self):
            getattr(self, f.name)[rows] = getattr(part, f.name)


#: Exact Python functions element by element: CPython's ``math`` results (``math.hypot``
#: is not libm's, numpy's SIMD cos/sin/pow are not either), so the array form of a
#: decision is the scalar one bit for bit.
hypot = np.frompyfunc(math.hypot, 2, 1)
power = np.frompyfunc(pow, 2, 1)
cos = np.frompyfunc(math.cos, 1, 1)
sin = np.frompyfunc(math.sin, 1, 1)
atan2 = np.frompyfunc(math.atan2, 2, 1)


def exact(fn, *args) -> np.ndarray:
    """``fn`` (one of the element-wise ``math`` functions above) as a float64 array."""
    return np.asarray(fn(*args), dtype=np.float64) if np.size(args[0]) else np.zeros(0)


def pick_slots(target: np.ndarray, ep: EpochArrays) -> tuple[np.ndarray, np.ndarray]:
    """Each run's target slot, for B runs: (slot, -1 for none; the new target id, -1
    for none). The current target while it is heard, else the first heard unmarked slot
    (the strongest: slots are ordered), else no slot and the target unchanged."""
    heard = ep.d >= 0
    cur = heard & (ep.ids == target[:, None]) & (target[:, None] >= 0)
    free = heard & (ep.ids >= 0) & ~ep.marked
    has_cur, has_free = cur.any(axis=1), free.any(axis=1)
    free_slot = free.argmax(axis=1)
    slot = np.where(has_cur, cur.argmax(axis=1), np.where(has_free, free_slot, -1))
    new = np.where(~has_cur & has_free, ep.ids[np.arange(target.size), free_slot], target)
    return slot, new


#: Controller phases in state arrays: FluxFollower uses the first two, ReceiverOnlySearch all.
SEARCH, FOLLOW, APPROACH, FINE = 0, 1, 2, 3
PHASE_NAMES = {SEARCH: "search", FOLLOW: "follow", APPROACH: "approach", FINE: "fine"}


#: Tick plan modes (:func:`~emulator.closed_loop.receiver_only.rx_plan`): what a controller
#: does on the ticks after an epoch until the next one, so a batch loop can replay them in
#: numpy. PLAN_CONST: hold (vx, vy); PLAN_SEARCH: the strip search velocity (at v_max; a
#: controller with ``search_sets_heading`` also sets its heading); PLAN_BACK: fly to (x, y)
#: at min(speed, dist / dt), and once within 2 cm the controller decides what comes next.
PLAN_CONST, PLAN_SEARCH, PLAN_BACK = 0, 1, 2


@dataclass(frozen=True)
class Located:
    """The controller's claim: transmitter ``id`` is under (x, y), found at time t."""

    id: int
    t: float
    x: float
    y: float


class StripSearch:
    """A lawnmower over (xmin, ymin, xmax, ymax): lanes along y, ``width`` apart, the
    first at xmin + width/2. Resumable: it remembers the next waypoint."""

    def __init__(self, area: tuple[float, float, float, float], width: float) -> None:
        xmin, ymin, xmax, ymax = area
        lanes = max(1, math.ceil((xmax - xmin) / width))
        self.waypoints: list[tuple[float, float]] = []
        for k in range(lanes):
            x = min(xmin + width / 2 + k * width, xmax)
            ends = [(x, ymin), (x, ymax)]
            self.waypoints += ends if k % 2 == 0 else ends[::-1]
        self.next = 0
        self._wp = np.array([self.waypoints], dtype=np.float64)
        self._count = np.array([len(self.waypoints)])

    @property
    def finished(self) -> bool:
        return self.next >= len(self.waypoints)

    def velocity(self, x: float, y: float, speed: float) -> tuple[float, float]:
        """:func:`strip_velocity` on a batch of one."""
        nxt = np.array([self.next])
        vx, vy = strip_velocity(self._wp, self._count, nxt, np.array([x]), np.array([y]), np.array([speed]))
        self.next = int(nxt[0])
        return float(vx[0]), float(vy[0])


def strip_velocity(wp, count, nxt, x, y, speed) -> tuple[np.ndarray, np.ndarray]:
    """The strip search's velocity for B runs: waypoints ``wp`` (B, W, 2) of which the
    first ``count`` (B,) are used, the next one ``nxt`` (B,; advanced in place past the
    waypoints within 0.25 m), at (x, y) and at most ``speed``: towards the next waypoint,
    arriving without overshooting at the next tick; (0, 0) once all are passed."""
    vx, vy = np.zeros(x.size), np.zeros(x.size)
    pending = np.arange(x.size)
    while pending.size:
        pending = pending[nxt[pending] < count[pending]]
        if not pending.size:
            break
        w = wp[pending, nxt[pending]]
        dx, dy = w[:, 0] - x[pending], w[:, 1] - y[pending]
        dist = exact(hypot, dx, dy)
        arrived = dist < 0.25
        nxt[pending[arrived]] += 1
        go = ~arrived
        g = pending[go]
        v = np.minimum(speed[g], dist[go])
        vx[g], vy[g] = dx[go] / dist[go] * v, dy[go] / dist[go] * v
        pending = pending[arrived]
    return vx, vy


class Controller:
    """Common parts: height hold, target selection with marking, signal search. A subclass
    keeps its state in ``state`` (:class:`StateArrays` of one run), read here as ``phase``
    ("search", ...) and ``target`` (an id or None)."""

    #: The search phase sets ``heading`` from each non-zero strip velocity.
    search_sets_heading = False

    def __init__(self, spec: VehicleSpec, dt: float | None = None) -> None:
        self.spec = spec
        self.dt = dt if dt is not None else 1.0 / spec.control_rate_hz
        self.located: list[Located] = []
        self.marked: set[int] = set()
        self.strips = StripSearch(spec.search_area, spec.strip_width) if spec.search_area else None

    phase = property(lambda self: PHASE_NAMES[int(self.state.phase[0])])
    target = property(lambda self: None if self.state.target[0] < 0 else int(self.state.target[0]))

    @property
    def exhausted(self) -> bool:
        """No signal to follow and nothing left of the search pattern (a controller
        without a search area waits for a signal: never exhausted)."""
        return self.phase == "search" and self.strips is not None and self.strips.finished

    def height_hold(self, obs: Observation) -> float:
        return self.spec.k_z * (self.spec.r_s - obs.height)

    def record(self, tx_id: int, t: float, x: float, y: float) -> None:
        """Transmitter ``tx_id`` located under (x, y) at time t: marked from now on."""
        self.located.append(Located(tx_id, t, x, y))
        self.marked.add(tx_id)

    def search_velocity(self, obs: Observation) -> tuple[float, float]:
        if self.strips is None:
            return 0.0, 0.0  # wait for a signal
        return self.strips.velocity(obs.x, obs.y, self.spec.v_max)

    def command(self, obs: Observation) -> tuple[float, float, float]:
        raise NotImplementedError


def speed_law(v_max, g):
    """v_max g / sqrt(1 + g^2): in [0, v_max), ~v_max for g >> 1, ~v_max g for g << 1.
    Floats or arrays (both square roots are correctly rounded: the same values)."""
    root = np.sqrt(1.0 + g * g) if isinstance(g, np.ndarray) else math.sqrt(1.0 + g * g)
    return v_max * g / root
