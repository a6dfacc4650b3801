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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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

    @property
    def finished(self) -> bool:
        return self.next >= len(self.waypoints)

    def velocity(self, x: float, y: float, speed: float) -> tuple[float, float]:
        while not self.finished:
            wx, wy = self.waypoints[self.next]
            dx, dy = wx - x, wy - y
            dist = math.hypot(dx, dy)
            if dist < 0.25:
                self.next += 1
                continue
            v = min(speed, dist)  # arrive without overshooting at the next tick
            return dx / dist * v, dy / dist * v
        return 0.0, 0.0


class Controller:
    """Common parts: height hold, target selection with marking, signal search."""

    name = "controller"
    #: The search phase sets ``heading`` from each non-zero strip velocity.
    search_sets_heading = False
    #: Reads ``Observation.field`` (a batch loop skips building it for those that do not).
    uses_field = True

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

    def slot_of(self, obs: Observation, tx_id: int | None) -> int | None:
        if tx_id is None:
            return None
        for i, (j, d) in enumerate(zip(obs.ids, obs.d)):
            if j == tx_id and d >= 0:
                return i
        return None

    def pick_target(self, obs: Observation) -> int | None:
        """The current target while it is heard, else the nearest unmarked transmitter."""
        slot = self.slot_of(obs, self.target)
        if slot is not None:
            return slot
        for i, (j, d) in enumerate(zip(obs.ids, obs.d)):
            if j >= 0 and d >= 0 and j not in self.marked:
                self.target = j
                return i
        return None

    def mark(self, obs: Observation, x: float, y: float) -> None:
        self.located.append(Located(self.target, obs.t, x, y))
        self.marked.add(self.target)
        self.target = None
        self.phase = "search"

    def search_velocity(self, obs: Observation) -> tuple[float, float]:
        if self.strips is None:
            return 0.0, 0.0  # wait for a signal
        return self.strips.velocity(obs.x, obs.y, self.spec.v_max)

    def command(self, obs: Observation) -> tuple[float, float, float]:
        raise NotImplementedError

    def tick_plan(self) -> TickPlan:
        """What :meth:`command` does until the next epoch (see :class:`TickPlan`)."""
        if self.phase == "search":
            return TickPlan(PLAN_CONST) if self.strips is None else TickPlan(PLAN_SEARCH)
        return TickPlan(PLAN_CONST, *self._v)


def speed_law(v_max: float, g: float) -> float:
    """v_max g / sqrt(1 + g^2): in [0, v_max), ~v_max for g >> 1, ~v_max g for g << 1."""
    return v_max * g / math.sqrt(1.0 + g * g)


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
        super().__init__(spec, model, dt)
        self._v = (0.0, 0.0)  # zero-order hold of V_xy between epochs
        self._settled = 0
        self._lost = 0
        self._following: int | None = None
        self._sign = 1.0
        self._best = math.inf
        self._since_flip = 0

    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            self._on_epoch(obs)
        if self.phase == "search":
            vx, vy = self.search_velocity(obs)
            return vx, vy, vz
        return self._v[0], self._v[1], vz

    def _on_epoch(self, obs: Observation) -> None:
        slot = self.pick_target(obs)
        if slot is None or obs.field is None:
            # A missing epoch (pulses, overlap) keeps the last command for a few epochs.
            self._lost += 1
            if self._lost > 3 or self.phase == "search":
                self.phase, self._v, self._settled = "search", (0.0, 0.0), 0
            return
        self._lost = 0
        self.phase = "follow"
        if self.target != self._following:
            self._following, self._sign, self._best, self._since_flip = self.target, 1.0, math.inf, 0
        hx, hy, hz = obs.field[slot]
        norm = math.sqrt(hx * hx + hy * hy + hz * hz)
        if not norm > 0.0:
            self._v = (0.0, 0.0)
            return
        rho = norm ** (-1.0 / 3.0)  # proportional to the distance, within a factor 1.26
        if self.spec.flux_reverse:
            self._since_flip += 1
            if rho < self._best:
                self._best = rho
            elif rho > self.REVERSE_GROWTH * self._best and self._since_flip >= self.REVERSE_EVERY:
                self._sign, self._best, self._since_flip = -self._sign, rho, 0
        s = self._sign * speed_law(self.spec.v_max, self.spec.k_c * rho) / norm
        # R_r h for a level receiver yawed by psi: rotate (hx, hy) by psi.
        c, si = math.cos(obs.yaw), math.sin(obs.yaw)
        self._v = (s * (c * hx - si * hy), s * (si * hx + c * hy))
        slow = math.hypot(*self._v) < self.spec.v_stop
        self._settled = self._settled + 1 if slow else 0
        if self._settled >= self.SETTLE_EPOCHS:
            self.mark(obs, obs.x, obs.y)
            self._v, self._settled, self._following = (0.0, 0.0), 0, None


@dataclass
class _Line:
    """One bracketing line: fly along +-u from (x0, y0), keep the minimum of d."""

    ux: float
    uy: float
    speed: float
    x0: float
    y0: float
    d_min: int
    x_min: float
    y_min: float
    sign: float = 1.0
    reversed: bool = False
    improved: bool = False
    going_back: bool = False


#: d of a missing reading during fine search: worse than any real one.
_NO_SIGNAL = 1 << 30


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
    """

    name = "receiver_only"
    search_sets_heading = True
    uses_field = False  # (id, d, delta) only
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
        super().__init__(spec, model, dt)
        # d (m) -> the |h|^(-1/3) of eq. 10: |h| = kappa_eq / (4 pi d^3).
        self.d_gain = (4.0 * math.pi / model.kappa_eq) ** (1.0 / 3.0)
        self.heading: float | None = None
        self._v = (0.0, 0.0)
        self._lost = 0
        self._approaching: int | None = None
        self._line: _Line | None = None
        self._queue: list[tuple[float, float]] = []  # (angle offset, speed) of lines to fly
        self._cross = 0
        self._attempts = 0  # fine searches that ended outside the inner zone
        self._commit = 0  # epochs left of following delta without turning around

    # -- per tick ---------------------------------------------------------------
    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            self._on_epoch(obs)
        if self.phase == "search":
            vx, vy = self.search_velocity(obs)
            if vx or vy:
                self.heading = math.atan2(vy, vx)
            return vx, vy, vz
        if self.phase == "fine":
            vx, vy = self._fine_velocity(obs)
            return vx, vy, vz
        return self._v[0], self._v[1], vz

    def tick_plan(self) -> TickPlan:
        if self.phase != "fine":
            return super().tick_plan()
        ln = self._line
        if ln is None:
            return TickPlan(PLAN_CONST)
        if ln.going_back:
            return TickPlan(PLAN_BACK, x=ln.x_min, y=ln.y_min, speed=ln.speed)
        return TickPlan(PLAN_CONST, ln.sign * ln.ux * ln.speed, ln.sign * ln.uy * ln.speed)

    # -- per epoch: coarse search -------------------------------------------------
    def _on_epoch(self, obs: Observation) -> None:
        slot = self.pick_target(obs)
        if self.phase == "fine":
            self._fine_epoch(obs, slot)
            return
        if slot is None:
            self._lost += 1
            if self._lost > 3 or self.phase == "search":
                self.phase, self._v = "search", (0.0, 0.0)
            return
        self._lost = 0
        d = obs.d[slot]
        if self.target != self._approaching:
            self._approaching, self._attempts, self._commit = self.target, 0, 0
            self.best_d, self.best_xy, self._since_best, self._since_flip, self._reversals = d, (obs.x, obs.y), 0, 0, 0
        self.phase = "approach"
        if d <= INNER_CM:
            self._start_fine(obs.x, obs.y, d)
            return
        bearing = obs.yaw + math.radians(obs.delta[slot])
        if self.heading is not None and math.cos(bearing - self.heading) < 0.0:
            bearing += math.pi  # the flux line's continuation, not its way back
        self._since_flip += 1
        if self._commit > 0:
            self._commit -= 1  # trust the arrow, whatever d does
        elif d < self.best_d:
            self.best_d, self.best_xy, self._since_best = d, (obs.x, obs.y), 0
        else:
            self._since_best += 1
            grown = d > self.best_d * (1.0 + self.REVERSE_FRACTION) + self.REVERSE_CM
            if grown and self._since_flip >= self.REVERSE_EVERY:
                bearing += math.pi  # distance grows: turn around
                self._since_flip = 0
                self._reversals += 1
        if self._reversals >= self.MAX_REVERSALS or self._since_best >= self.STUCK_EPOCHS:
            self._start_fine(self.best_xy[0], self.best_xy[1], self.best_d, obs)
            return
        self.heading = math.atan2(math.sin(bearing), math.cos(bearing))
        s = speed_law(self.spec.v_max, self.spec.k_c * self.d_gain * d / 100.0)
        self._v = (s * math.cos(self.heading), s * math.sin(self.heading))

    # -- fine search (bracketing) -----------------------------------------------
    def _start_fine(self, x: float, y: float, d: int, obs: Observation | None = None) -> None:
        """Bracket around (x, y); when that is not where we are (stuck), fly there first."""
        self.phase = "fine"
        self._base = self.heading if self.heading is not None else 0.0
        self._cross = 0
        self._queue_cross()
        if obs is not None and math.hypot(x - obs.x, y - obs.y) > 0.02:
            self._line = _Line(1.0, 0.0, self.spec.v_max, obs.x, obs.y, d, x, y, going_back=True)
        else:
            self._next_line(x, y, d)

    def _queue_cross(self) -> None:
        v = self.spec.v_fine if self._cross == 0 else self.spec.v_fine / 2
        self._queue = [(0.0, v), (math.pi / 2, v)]

    def _next_line(self, x: float, y: float, d: int) -> None:
        offset, speed = self._queue.pop(0)
        a = self._base + offset
        self._line = _Line(math.cos(a), math.sin(a), speed, x, y, d, x, y)

    def _fine_epoch(self, obs: Observation, slot: int | None) -> None:
        ln = self._line
        if ln is None or ln.going_back:
            return
        d = obs.d[slot] if slot is not None else _NO_SIGNAL
        along = ln.sign * ((obs.x - ln.x0) * ln.ux + (obs.y - ln.y0) * ln.uy)
        if d < ln.d_min and along > 0.0:
            ln.d_min, ln.x_min, ln.y_min, ln.improved = d, obs.x, obs.y, True
            return
        if along <= 0.0:
            return  # turned around and not yet back past the line's start
        travelled = math.hypot(obs.x - ln.x0, obs.y - ln.y0)
        if d >= ln.d_min + self.RISE_CM or travelled > self.MAX_LINE_M:
            if not ln.improved and not ln.reversed:
                ln.sign, ln.reversed = -ln.sign, True  # worse from the start: the other way
            else:
                ln.going_back = True

    def _fine_velocity(self, obs: Observation) -> tuple[float, float]:
        ln = self._line
        if ln is None:
            return 0.0, 0.0
        if not ln.going_back:
            return ln.sign * ln.ux * ln.speed, ln.sign * ln.uy * ln.speed
        dx, dy = ln.x_min - obs.x, ln.y_min - obs.y
        dist = math.hypot(dx, dy)
        if dist >= 0.02:
            v = min(ln.speed, dist / self.dt)  # arrive on the minimum without overshoot
            return dx / dist * v, dy / dist * v
        # On this line's minimum: the next line, the next cross, or done.
        if not self._queue:
            self._cross += 1
            done = self._cross >= 2 and ln.d_min <= INNER_CM
            done |= self._cross >= 3 and (ln.d_min <= self.PROBE_CM or self._attempts >= self.MAX_ATTEMPTS)
            if done:
                self.mark(obs, ln.x_min, ln.y_min)
                self._line, self._approaching = None, None
                return 0.0, 0.0
            if self._cross >= 3:
                # A minimum of the two-antenna d outside the inner zone is a trap near a
                # steep dipole: follow the arrow for a while without turning, then retry.
                self._attempts += 1
                self._commit, self._since_best, self._reversals = self.COMMIT_EPOCHS, 0, 0
                self.best_d, self.best_xy = _NO_SIGNAL, (obs.x, obs.y)
                self.phase, self._line = "approach", None
                return 0.0, 0.0
            self._queue_cross()
        self._next_line(obs.x, obs.y, ln.d_min)
        return self._fine_velocity(obs)


def make_controller(spec: VehicleSpec, model: ModelParams = ModelParams()) -> Controller:
    if spec.controller == "flux":
        return FluxFollower(spec, model)
    if spec.controller == "receiver_only":
        return ReceiverOnlySearch(spec, model)
    raise ValueError(f"no onboard controller for {spec.controller!r}")
