"""Search strategies flown in closed loop: velocity commands from receiver output.

Two strategies, both with the paper's height hold V_z = k_z (r_s - y_s) (section IV):

* :class:`FluxFollower` — the paper's flux-line follower, eq. 10, on the full field
  vector ^r h (what a research receiver gives as ``$PARVH``, arva_sim's ``direction``)::

      V_xy = L_xy v_max g / sqrt(1 + g^2) R_r h / |h|,    g = k_c |h|^(-1/3)

  The speed g/sqrt(1+g^2) v_max falls towards 0 as |h| grows near the transmitter; the
  direction is the field in the world frame. Located: |V_xy| < v_stop on three
  consecutive epochs — the drone has settled where the field is vertical, which for a
  horizontal dipole dz below the flight height is dz/sqrt(2) from its ground
  projection (towards its -x end).

* :class:`ReceiverOnlySearch` — only (id, d, delta), the way a rescuer uses a
  commercial receiver: (1) signal search along strips; (2) coarse search: follow the
  flux line by delta (folded to +-90 deg, so the continuation closest to the current
  heading is taken, and the heading is reversed when d grows: "if the distance
  increases, turn around"), slowing down with d by the same law as eq. 10 with
  |h|^(-1/3) replaced by its value (4 pi / kappa_eq)^(1/3) d; (3) fine search in the
  inner zone (delta = 0): bracketing along a line and then across it, at the minimum
  of d each time, twice (the second cross at half speed); located at the last minimum.
  (Details and the escape from the mid zone's "d grows near a steep dipole" trap in
  :class:`ReceiverOnlySearch`.)

Both search for a signal with a lawnmower over ``search_area`` (strips ``strip_width``
apart) when one is given, else they wait for a signal (the paper: "after taking off,
the UAV waits for a valid ARVA signal"). With several transmitters, a located one is
*marked* (its id ignored from then on, as receivers' "mark" function does) and the
search goes on with the nearest unmarked one, or resumes the strips.

Controllers see an :class:`Observation` per control tick: the vehicle's own position and
yaw (its navigation solution), the range-sensor reading, and the latest receiver epoch
(held between epochs; ``new_epoch`` is true on the tick it arrived).

**Written once, over arrays of runs.** The decisions (:func:`flux_epoch`;
:func:`rx_epoch`, :func:`rx_plan`, :func:`fly_back`, :func:`rx_arrive`;
:func:`strip_velocity`) take the state
of B runs as numpy arrays (:class:`FluxState`, :class:`RxState`, one element per run)
and an epoch as arrays (:class:`EpochArrays`). A controller object (what
:class:`~emulator.closed_loop.loop.ClosedLoop` flies) holds the state of one run and
calls them with B = 1; :class:`~emulator.closed_loop.batch.BatchLoop` calls them with all
runs of a strategy. The ``math`` functions numpy does not reproduce bit for bit (hypot,
atan2, cos, sin, pow) are applied element by element with CPython's own, so a run's
decisions do not depend on the batch it is in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from emulator.receiver.model import ModelParams
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
    """Controller state as numpy arrays, one element per run: a dataclass of arrays
    whose rows can be taken out (:meth:`take`) and put back (:meth:`put`)."""

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
_hypot = np.frompyfunc(math.hypot, 2, 1)
_pow = np.frompyfunc(pow, 2, 1)
_cos = np.frompyfunc(math.cos, 1, 1)
_sin = np.frompyfunc(math.sin, 1, 1)
_atan2 = np.frompyfunc(math.atan2, 2, 1)


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


#: Controller phases in state arrays.
SEARCH, FOLLOW = 0, 1
_PHASE_NAMES = {SEARCH: "search", FOLLOW: "follow"}


@dataclass
class FluxState(StateArrays):
    """:class:`FluxFollower` state, one element per run."""

    phase: np.ndarray = SEARCH
    target: np.ndarray = -1
    vx: np.ndarray = 0.0  # zero-order hold of V_xy between epochs
    vy: np.ndarray = 0.0
    settled: np.ndarray = 0
    lost: np.ndarray = 0
    following: np.ndarray = -1
    sign: np.ndarray = 1.0
    best: np.ndarray = math.inf
    since_flip: np.ndarray = 0


@dataclass
class FluxParams:
    """:class:`FluxFollower` constants per run (from its :class:`VehicleSpec`)."""

    v_max: np.ndarray
    k_c: np.ndarray
    v_stop: np.ndarray
    reverse: np.ndarray

    @classmethod
    def of(cls, specs: list[VehicleSpec]) -> "FluxParams":
        return cls(np.array([s.v_max for s in specs], dtype=np.float64), np.array([s.k_c for s in specs], dtype=np.float64),
                   np.array([s.v_stop for s in specs], dtype=np.float64), np.array([s.flux_reverse for s in specs]))

    def take(self, rows: np.ndarray) -> "FluxParams":
        return FluxParams(self.v_max[rows], self.k_c[rows], self.v_stop[rows], self.reverse[rows])


def flux_epoch(st: FluxState, ep: EpochArrays, par: FluxParams) -> tuple[np.ndarray, np.ndarray]:
    """:class:`FluxFollower`'s decision on a new epoch, for B runs at once (the one copy
    of that logic: a single FluxFollower runs it with B = 1). Updates ``st`` in place;
    returns (mask of the runs that located their target now, the ids they located):
    the caller records those (:meth:`Controller.mark` without the state part, done here).
    """
    n = st.phase.size
    slot, st.target[:] = pick_slots(st.target, ep)
    ok = slot >= 0 if ep.field is not None else np.zeros(n, dtype=bool)
    # A missing epoch (pulses, overlap) keeps the last command for a few epochs.
    miss = ~ok
    st.lost[miss] += 1
    reset = miss & ((st.lost > 3) | (st.phase == SEARCH))
    st.phase[reset], st.vx[reset], st.vy[reset], st.settled[reset] = SEARCH, 0.0, 0.0, 0
    st.lost[ok] = 0
    st.phase[ok] = FOLLOW
    new = ok & (st.target != st.following)
    st.following[new], st.sign[new], st.best[new], st.since_flip[new] = st.target[new], 1.0, math.inf, 0
    marks = np.zeros(n, dtype=bool)
    g = np.flatnonzero(ok)
    if not g.size:
        return marks, st.target[marks]
    h = ep.field[g, slot[g]]
    hx, hy, hz = h[:, 0], h[:, 1], h[:, 2]
    norm = np.sqrt(hx * hx + hy * hy + hz * hz)
    flat = ~(norm > 0.0)
    st.vx[g[flat]], st.vy[g[flat]] = 0.0, 0.0
    go = ~flat
    g, hx, hy, norm = g[go], hx[go], hy[go], norm[go]
    rho = exact(_pow, norm, -1.0 / 3.0)  # proportional to the distance, within a factor 1.26
    sign, best, since = st.sign[g], st.best[g], st.since_flip[g]
    rev = par.reverse[g]
    since = since + rev
    better = rho < best
    flip = rev & ~better & (rho > FluxFollower.REVERSE_GROWTH * best) & (since >= FluxFollower.REVERSE_EVERY)
    best = np.where(rev & better, rho, best)
    sign = np.where(flip, -sign, sign)
    best = np.where(flip, rho, best)
    since = np.where(flip, 0, since)
    st.sign[g], st.best[g], st.since_flip[g] = sign, best, since
    s = sign * speed_law(par.v_max[g], par.k_c[g] * rho) / norm
    # R_r h for a level receiver yawed by psi: rotate (hx, hy) by psi.
    c, si = exact(_cos, ep.yaw[g]), exact(_sin, ep.yaw[g])
    vx, vy = s * (c * hx - si * hy), s * (si * hx + c * hy)
    slow = exact(_hypot, vx, vy) < par.v_stop[g]
    settled = np.where(slow, st.settled[g] + 1, 0)
    st.vx[g], st.vy[g], st.settled[g] = vx, vy, settled
    marks[g] = settled >= FluxFollower.SETTLE_EPOCHS
    located = st.target[marks]
    st.target[marks], st.phase[marks], st.following[marks] = -1, SEARCH, -1
    st.vx[marks], st.vy[marks], st.settled[marks] = 0.0, 0.0, 0
    return marks, located


#: :class:`TickPlan` modes.
PLAN_CONST, PLAN_SEARCH, PLAN_BACK = 0, 1, 2


@dataclass(slots=True)
class TickPlan:
    """What :meth:`Controller.command` does on the ticks after an epoch (``new_epoch``
    false) until the next one, so a batch loop can replay those ticks in numpy:

    * ``PLAN_CONST``: return (``vx``, ``vy``) every tick;
    * ``PLAN_SEARCH``: the strip search velocity (:meth:`StripSearch.velocity` at
      ``spec.v_max``; a controller with ``search_sets_heading`` also sets ``heading``);
    * ``PLAN_BACK``: fly to (``x``, ``y``) at min(``speed``, dist / dt); once within
      2 cm the controller itself decides what comes next (call :meth:`command`).
    """

    mode: int
    vx: float = 0.0
    vy: float = 0.0
    x: float = 0.0
    y: float = 0.0
    speed: float = 0.0


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
        dist = exact(_hypot, dx, dy)
        arrived = dist < 0.25
        nxt[pending[arrived]] += 1
        go = ~arrived
        g = pending[go]
        v = np.minimum(speed[g], dist[go])
        vx[g], vy[g] = dx[go] / dist[go] * v, dy[go] / dist[go] * v
        pending = pending[arrived]
    return vx, vy


class Controller:
    """Common parts: height hold, target selection with marking, signal search."""

    name = "controller"
    #: The search phase sets ``heading`` from each non-zero strip velocity.
    search_sets_heading = False

    def __init__(self, spec: VehicleSpec, model: ModelParams = ModelParams(), dt: float | None = None) -> None:
        self.spec = spec
        self.model = model
        self.dt = dt if dt is not None else 1.0 / spec.control_rate_hz
        self.located: list[Located] = []
        self.marked: set[int] = set()
        self.target: int | None = None
        self.strips = StripSearch(spec.search_area, spec.strip_width) if spec.search_area else None
        self.phase = "search"

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


class FluxFollower(Controller):
    """The paper's eq. 10 on the full receiver-frame field vector (see module doc).

    With ``flux_reverse`` (not in the paper) it follows -h instead of +h while the
    distance proxy |h|^(-1/3) keeps growing (10 % above its best, at most every 5
    epochs): eq. 10 with +h only flies away from a dipole that points upwards, whose
    field in the flight plane diverges from the point above it.
    """

    name = "flux"
    SETTLE_EPOCHS = 3
    REVERSE_GROWTH = 1.1
    REVERSE_EVERY = 5

    def __init__(self, spec: VehicleSpec, model: ModelParams = ModelParams(), dt: float | None = None) -> None:
        self.state = FluxState.empty(1)  # this run's state: flux_epoch on a batch of one
        self.params = FluxParams.of([spec])
        super().__init__(spec, model, dt)

    # The state array's element, under the names the rest of the code reads.
    phase = property(lambda self: _PHASE_NAMES[int(self.state.phase[0])],
                     lambda self, name: self.state.phase.__setitem__(0, SEARCH if name == "search" else FOLLOW))
    target = property(lambda self: None if self.state.target[0] < 0 else int(self.state.target[0]),
                      lambda self, tx_id: self.state.target.__setitem__(0, -1 if tx_id is None else tx_id))
    _v = property(lambda self: (float(self.state.vx[0]), float(self.state.vy[0])))

    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            self._on_epoch(obs)
        if self.phase == "search":
            vx, vy = self.search_velocity(obs)
            return vx, vy, vz
        return self._v[0], self._v[1], vz

    def _on_epoch(self, obs: Observation) -> None:
        marks, ids = flux_epoch(self.state, EpochArrays.of(obs, self.marked), self.params)
        if marks[0]:
            self.record(int(ids[0]), obs.t, obs.x, obs.y)


#: d of a missing reading during fine search: worse than any real one.
_NO_SIGNAL = 1 << 30

#: Further phases in state arrays (ReceiverOnlySearch).
APPROACH, FINE = 2, 3
_PHASE_NAMES.update({APPROACH: "approach", FINE: "fine"})
_radians = np.frompyfunc(math.radians, 1, 1)


@dataclass
class RxState(StateArrays):
    """:class:`ReceiverOnlySearch` state, one element per run. The fine search's
    current line (``line``: one is set; fly along +-(ux, uy) from (x0, y0) at ``speed``,
    keeping the minimum ``d_min`` of d and where it was) and the lines queued after it
    (``queued`` of the two of a cross, both at ``queue_speed``)."""

    phase: np.ndarray = SEARCH
    target: np.ndarray = -1
    heading: np.ndarray = 0.0  # rad, ENU; valid when ``headed``
    headed: np.ndarray = False
    vx: np.ndarray = 0.0
    vy: np.ndarray = 0.0
    lost: np.ndarray = 0
    approaching: np.ndarray = -1
    best_d: np.ndarray = 0
    best_x: np.ndarray = 0.0
    best_y: np.ndarray = 0.0
    since_best: np.ndarray = 0
    since_flip: np.ndarray = 0
    reversals: np.ndarray = 0
    attempts: np.ndarray = 0  # fine searches that ended outside the inner zone
    commit: np.ndarray = 0  # epochs left of following delta without turning around
    base: np.ndarray = 0.0
    cross: np.ndarray = 0
    queued: np.ndarray = 0
    queue_speed: np.ndarray = 0.0
    line: np.ndarray = False
    ux: np.ndarray = 0.0
    uy: np.ndarray = 0.0
    speed: np.ndarray = 0.0
    x0: np.ndarray = 0.0
    y0: np.ndarray = 0.0
    d_min: np.ndarray = 0
    x_min: np.ndarray = 0.0
    y_min: np.ndarray = 0.0
    sign: np.ndarray = 1.0
    reversed: np.ndarray = False
    improved: np.ndarray = False
    going_back: np.ndarray = False


@dataclass
class RxParams:
    """:class:`ReceiverOnlySearch` constants per run: v_max, k_c, v_fine (spec) and
    d_gain (d in m -> the |h|^(-1/3) of eq. 10: |h| = kappa_eq / (4 pi d^3))."""

    v_max: np.ndarray
    k_c: np.ndarray
    v_fine: np.ndarray
    d_gain: np.ndarray

    @classmethod
    def of(cls, specs: list[VehicleSpec], model: ModelParams) -> "RxParams":
        gain = (4.0 * math.pi / model.kappa_eq) ** (1.0 / 3.0)
        col = lambda name: np.array([getattr(s, name) for s in specs], dtype=np.float64)  # noqa: E731
        return cls(col("v_max"), col("k_c"), col("v_fine"), np.full(len(specs), gain))

    def take(self, rows: np.ndarray) -> "RxParams":
        return RxParams(self.v_max[rows], self.k_c[rows], self.v_fine[rows], self.d_gain[rows])


def rx_epoch(st: RxState, ep: EpochArrays, par: RxParams) -> None:
    """:class:`ReceiverOnlySearch`'s decision on a new epoch, for B runs at once (the one
    copy of that logic: a single ReceiverOnlySearch runs it with B = 1); updates ``st``."""
    R = ReceiverOnlySearch
    n = st.phase.size
    slot, st.target[:] = pick_slots(st.target, ep)
    heard = slot >= 0
    d = np.where(heard, ep.d[np.arange(n), slot], _NO_SIGNAL)
    fine = st.phase == FINE
    f = np.flatnonzero(fine & st.line & ~st.going_back)
    if f.size:
        _fine_epoch(st, f, ep.x[f], ep.y[f], d[f])
    miss = ~fine & ~heard
    st.lost[miss] += 1
    reset = miss & ((st.lost > 3) | (st.phase == SEARCH))
    st.phase[reset], st.vx[reset], st.vy[reset] = SEARCH, 0.0, 0.0
    c = np.flatnonzero(~fine & heard)
    if not c.size:
        return
    st.lost[c] = 0
    d, x, y = d[c], ep.x[c], ep.y[c]
    new = st.target[c] != st.approaching[c]
    r = c[new]
    st.approaching[r], st.attempts[r], st.commit[r] = st.target[r], 0, 0
    st.best_d[r], st.best_x[r], st.best_y[r] = d[new], x[new], y[new]
    st.since_best[r], st.since_flip[r], st.reversals[r] = 0, 0, 0
    st.phase[c] = APPROACH
    inner = d <= INNER_CM
    if inner.any():
        _start_fine(st, c[inner], x[inner], y[inner], d[inner], par)
    keep = ~inner
    c, d, x, y = c[keep], d[keep], x[keep], y[keep]
    if not c.size:
        return
    bearing = ep.yaw[c] + exact(_radians, ep.delta[c, slot[c]])
    h = st.headed[c]
    back = np.zeros(c.size, dtype=bool)
    back[h] = exact(_cos, bearing[h] - st.heading[c[h]]) < 0.0
    bearing = np.where(back, bearing + math.pi, bearing)  # the flux line's continuation, not its way back
    st.since_flip[c] += 1
    commit = st.commit[c] > 0
    st.commit[c[commit]] -= 1  # trust the arrow, whatever d does
    better = ~commit & (d < st.best_d[c])
    r = c[better]
    st.best_d[r], st.best_x[r], st.best_y[r], st.since_best[r] = d[better], x[better], y[better], 0
    worse = ~commit & ~better
    r = c[worse]
    st.since_best[r] += 1
    grown = d[worse] > st.best_d[r] * (1.0 + R.REVERSE_FRACTION) + R.REVERSE_CM
    turn = np.zeros(c.size, dtype=bool)
    turn[worse] = grown & (st.since_flip[r] >= R.REVERSE_EVERY)
    bearing = np.where(turn, bearing + math.pi, bearing)  # distance grows: turn around
    st.since_flip[c[turn]] = 0
    st.reversals[c[turn]] += 1
    stuck = (st.reversals[c] >= R.MAX_REVERSALS) | (st.since_best[c] >= R.STUCK_EPOCHS)
    if stuck.any():
        r = c[stuck]
        _start_fine(st, r, st.best_x[r], st.best_y[r], st.best_d[r], par, x[stuck], y[stuck])
    go = ~stuck
    c, bearing, d = c[go], bearing[go], d[go]
    heading = exact(_atan2, exact(_sin, bearing), exact(_cos, bearing))
    st.heading[c], st.headed[c] = heading, True
    s = speed_law(par.v_max[c], par.k_c[c] * par.d_gain[c] * d / 100.0)
    st.vx[c], st.vy[c] = s * exact(_cos, heading), s * exact(_sin, heading)


def _start_fine(st: RxState, r, x, y, d, par: RxParams, from_x=None, from_y=None) -> None:
    """Bracket around (x, y); when that is not where we are, (from_x, from_y) (stuck),
    fly there first."""
    st.phase[r] = FINE
    st.base[r] = np.where(st.headed[r], st.heading[r], 0.0)
    st.cross[r] = 0
    _queue_cross(st, r, par)
    back = np.zeros(r.size, dtype=bool)
    if from_x is not None:
        back = exact(_hypot, x - from_x, y - from_y) > 0.02
    b = r[back]
    if b.size:
        _set_line(st, b, 1.0, 0.0, par.v_max[b], from_x[back], from_y[back], d[back], x[back], y[back])
        st.going_back[b] = True
    keep = ~back
    if keep.any():
        _next_line(st, r[keep], x[keep], y[keep], d[keep])


def _queue_cross(st: RxState, r, par: RxParams) -> None:
    st.queued[r] = 2  # along the base heading, then across it
    st.queue_speed[r] = np.where(st.cross[r] == 0, par.v_fine[r], par.v_fine[r] / 2)


def _set_line(st: RxState, r, ux, uy, speed, x0, y0, d, x, y) -> None:
    st.line[r], st.ux[r], st.uy[r], st.speed[r], st.x0[r], st.y0[r] = True, ux, uy, speed, x0, y0
    st.d_min[r], st.x_min[r], st.y_min[r] = d, x, y
    st.sign[r], st.reversed[r], st.improved[r], st.going_back[r] = 1.0, False, False, False


def _next_line(st: RxState, r, x, y, d) -> None:
    a = st.base[r] + np.where(st.queued[r] == 2, 0.0, math.pi / 2)
    speed = st.queue_speed[r]
    st.queued[r] -= 1
    _set_line(st, r, exact(_cos, a), exact(_sin, a), speed, x, y, d, x, y)


def _fine_epoch(st: RxState, r, x, y, d) -> None:
    """A new epoch on a fine-search line (not on its way back)."""
    R = ReceiverOnlySearch
    along = st.sign[r] * ((x - st.x0[r]) * st.ux[r] + (y - st.y0[r]) * st.uy[r])
    ahead = along > 0.0  # else: turned around and not yet back past the line's start
    better = ahead & (d < st.d_min[r])
    b = r[better]
    st.d_min[b], st.x_min[b], st.y_min[b], st.improved[b] = d[better], x[better], y[better], True
    rest = ahead & ~better
    e = r[rest]
    travelled = exact(_hypot, x[rest] - st.x0[e], y[rest] - st.y0[e])
    end = (d[rest] >= st.d_min[e] + R.RISE_CM) | (travelled > R.MAX_LINE_M)
    e = e[end]
    turn = ~st.improved[e] & ~st.reversed[e]  # worse from the start: the other way
    t = e[turn]
    st.sign[t], st.reversed[t] = -st.sign[t], True
    st.going_back[e[~turn]] = True


def rx_plan(st: RxState, has_strips: np.ndarray) -> tuple[np.ndarray, ...]:
    """:meth:`ReceiverOnlySearch.tick_plan` for B runs: (mode, vx, vy, x, y, speed)."""
    n = st.phase.size
    mode = np.full(n, PLAN_CONST, dtype=np.int8)
    vx, vy = st.vx.copy(), st.vy.copy()
    search = st.phase == SEARCH
    mode[search & has_strips] = PLAN_SEARCH
    fine = st.phase == FINE
    still = search | (fine & ~st.line)
    vx[still], vy[still] = 0.0, 0.0
    along = fine & st.line & ~st.going_back
    vx[along] = st.sign[along] * st.ux[along] * st.speed[along]
    vy[along] = st.sign[along] * st.uy[along] * st.speed[along]
    back = fine & st.line & st.going_back
    mode[back] = PLAN_BACK
    return mode, vx, vy, st.x_min, st.y_min, st.speed


def fly_back(bx, by, speed, x, y, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:data:`PLAN_BACK` for B runs: fly to (bx, by) at min(speed, dist / dt), arriving
    without overshoot; (vx, vy, arrived): arrived (within 2 cm) runs get (0, 0) and the
    controller decides (:func:`rx_arrive`)."""
    dx, dy = bx - x, by - y
    dist = exact(_hypot, dx, dy)
    go = dist >= 0.02
    vx, vy = np.zeros(dist.size), np.zeros(dist.size)
    v = np.minimum(speed[go], dist[go] / dt)
    vx[go] = dx[go] / dist[go] * v
    vy[go] = dy[go] / dist[go] * v
    return vx, vy, ~go


def rx_arrive(st: RxState, x, y, par: RxParams) -> tuple[np.ndarray, ...]:
    """B runs that arrived on their fine-search line's minimum at (x, y): the next line,
    the next cross, located, or a retry. Returns (located mask, their ids, where: x, y;
    the tick's vx, vy)."""
    R = ReceiverOnlySearch
    n = st.phase.size
    r = np.arange(n)
    empty = st.queued == 0
    st.cross[empty] += 1
    cross, d_min = st.cross, st.d_min
    done = empty & (cross >= 2) & (d_min <= INNER_CM)
    done |= empty & (cross >= 3) & ((d_min <= R.PROBE_CM) | (st.attempts >= R.MAX_ATTEMPTS))
    located, lx, ly = st.target[done], st.x_min[done], st.y_min[done]
    st.target[done], st.phase[done], st.line[done], st.approaching[done] = -1, SEARCH, False, -1
    # A minimum of the two-antenna d outside the inner zone is a trap near a steep
    # dipole: follow the arrow for a while without turning, then retry.
    retry = empty & ~done & (cross >= 3)
    t = r[retry]
    st.attempts[t] += 1
    st.commit[t], st.since_best[t], st.reversals[t] = R.COMMIT_EPOCHS, 0, 0
    st.best_d[t], st.best_x[t], st.best_y[t] = _NO_SIGNAL, x[retry], y[retry]
    st.phase[t], st.line[t] = APPROACH, False
    requeue = empty & ~done & ~retry
    _queue_cross(st, r[requeue], par)
    nxt = ~done & ~retry
    _next_line(st, r[nxt], x[nxt], y[nxt], d_min[nxt])
    vx, vy = np.zeros(n), np.zeros(n)
    vx[nxt] = st.sign[nxt] * st.ux[nxt] * st.speed[nxt]
    vy[nxt] = st.sign[nxt] * st.uy[nxt] * st.speed[nxt]
    return done, located, lx, ly, vx, vy


class ReceiverOnlySearch(Controller):
    """A rescuer's procedure on (id, d, delta) only (see module doc).

    Coarse search: the heading is the flux line's bearing yaw + delta, or its opposite,
    whichever continues the current heading; it is reversed when d exceeds the best
    seen on this approach by 10 % + 1 m (at most every 5 epochs). Near a steeply tilted
    transmitter the two-antenna mid-zone d grows while the true distance falls (the
    field turns vertical, |(h_x, h_y)| shrinks); a rescuer that keeps turning there is
    stuck, so after 3 reversals or 20 epochs without a new best d the fine search
    starts from the best point seen.

    Fine search (inner zone, or stuck): crosses of two bracketing lines (along the
    heading, then across it); each line flies until d is ``RISE_CM`` above its minimum
    (turning once if it got worse from the start) or ``MAX_LINE_M`` each way, then
    returns to the minimum. Cross 1 at v_fine, then at v_fine / 2; located after two
    crosses when the minimum is in the inner zone, else after the third if the minimum
    is below ``PROBE_CM`` (a deep burial: probe there). A minimum above that is the
    steep-dipole trap: follow delta for ``COMMIT_EPOCHS`` without turning around and
    search again; after ``MAX_ATTEMPTS`` such retries, the best point is reported.

    The logic is written once over arrays of runs (:func:`rx_epoch`, :func:`rx_plan`,
    :func:`fly_back`, :func:`rx_arrive`); this object runs it on a batch of one, a
    batch loop on many runs together.
    """

    name = "receiver_only"
    search_sets_heading = True
    REVERSE_FRACTION = 0.1
    REVERSE_CM = 100
    REVERSE_EVERY = 5
    STUCK_EPOCHS = 20
    MAX_REVERSALS = 3
    RISE_CM = 5
    MAX_LINE_M = 6.0
    COMMIT_EPOCHS = 30
    #: A fine-search minimum up to this d (cm) is a deep burial, not a trap: probe there.
    PROBE_CM = 500
    MAX_ATTEMPTS = 2

    def __init__(self, spec: VehicleSpec, model: ModelParams = ModelParams(), dt: float | None = None) -> None:
        self.state = RxState.empty(1)
        self.params = RxParams.of([spec], model)
        super().__init__(spec, model, dt)
        self._plan = self.tick_plan()

    phase = property(lambda self: _PHASE_NAMES[int(self.state.phase[0])],
                     lambda self, name: self.state.phase.__setitem__(0, SEARCH if name == "search" else FINE))
    target = FluxFollower.target
    heading = property(lambda self: float(self.state.heading[0]) if self.state.headed[0] else None)

    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            rx_epoch(self.state, EpochArrays.of(obs, self.marked), self.params)
            self._plan = self.tick_plan()
        plan = self._plan
        if plan.mode == PLAN_SEARCH:
            vx, vy = self.search_velocity(obs)
            if vx or vy:
                self.state.heading[0], self.state.headed[0] = math.atan2(vy, vx), True
            return vx, vy, vz
        if plan.mode == PLAN_BACK:
            x, y = np.array([obs.x]), np.array([obs.y])
            vx, vy, arrived = fly_back(np.array([plan.x]), np.array([plan.y]), np.array([plan.speed]), x, y, self.dt)
            if arrived[0]:
                marks, ids, lx, ly, vx, vy = rx_arrive(self.state, x, y, self.params)
                if marks[0]:
                    self.record(int(ids[0]), obs.t, float(lx[0]), float(ly[0]))
                self._plan = self.tick_plan()
            return float(vx[0]), float(vy[0]), vz
        return plan.vx, plan.vy, vz

    def tick_plan(self) -> TickPlan:
        mode, vx, vy, x, y, speed = rx_plan(self.state, np.array([self.strips is not None]))
        return TickPlan(int(mode[0]), float(vx[0]), float(vy[0]), float(x[0]), float(y[0]), float(speed[0]))


def make_controller(spec: VehicleSpec, model: ModelParams = ModelParams()) -> Controller:
    if spec.controller == "flux":
        return FluxFollower(spec, model)
    if spec.controller == "receiver_only":
        return ReceiverOnlySearch(spec, model)
    raise ValueError(f"no onboard controller for {spec.controller!r}")
