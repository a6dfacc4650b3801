"""The receiver-only search (only id, d, delta, as a rescuer uses a commercial receiver):
signal search, coarse search along the flux line by delta, fine search by bracketing;
over arrays of runs (:func:`rx_epoch`, :func:`rx_plan`, :func:`fly_back`,
:func:`rx_arrive`) and as a per-run :class:`ReceiverOnlySearch`; see
emulator.closed_loop.controllers for the overview. d centimetres, delta degrees,
positions ENU metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from emulator.closed_loop.strategy import (
    APPROACH, FINE, INNER_CM, PLAN_BACK, PLAN_CONST, PLAN_SEARCH, SEARCH, Controller, EpochArrays,
    Observation, StateArrays, atan2, cos, exact, hypot, pick_slots, sin, speed_law,
)
from emulator.closed_loop.vehicle import VehicleSpec
from emulator.receiver.model import ModelParams

#: d of a missing reading during fine search: worse than any real one.
_NO_SIGNAL = 1 << 30

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
class RxParams(StateArrays):
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
    back[h] = exact(cos, bearing[h] - st.heading[c[h]]) < 0.0
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
    heading = exact(atan2, exact(sin, bearing), exact(cos, bearing))
    st.heading[c], st.headed[c] = heading, True
    s = speed_law(par.v_max[c], par.k_c[c] * par.d_gain[c] * d / 100.0)
    st.vx[c], st.vy[c] = s * exact(cos, heading), s * exact(sin, heading)


def _start_fine(st: RxState, r, x, y, d, par: RxParams, from_x=None, from_y=None) -> None:
    """Bracket around (x, y); when that is not where we are, (from_x, from_y) (stuck),
    fly there first."""
    st.phase[r] = FINE
    st.base[r] = np.where(st.headed[r], st.heading[r], 0.0)
    st.cross[r] = 0
    _queue_cross(st, r, par)
    back = np.zeros(r.size, dtype=bool)
    if from_x is not None:
        back = exact(hypot, x - from_x, y - from_y) > 0.02
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
    _set_line(st, r, exact(cos, a), exact(sin, a), speed, x, y, d, x, y)


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
    travelled = exact(hypot, x[rest] - st.x0[e], y[rest] - st.y0[e])
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
    dist = exact(hypot, dx, dy)
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
    """A rescuer's procedure on (id, d, delta) only: docs/closed_loop.md, "Strategies",
    describes its coarse search, fine search and steep-dipole trap, whose numbers are the
    constants below. This object runs the array logic (:func:`rx_epoch` ...) on a batch
    of one."""

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
        super().__init__(spec, dt)
        self._plan = self.tick_plan()

    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            rx_epoch(self.state, EpochArrays.of(obs, self.marked), self.params)
            self._plan = self.tick_plan()
        mode, vx, vy, bx, by, speed = self._plan
        if mode[0] == PLAN_SEARCH:
            vx, vy = self.search_velocity(obs)
            if vx or vy:
                self.state.heading[0], self.state.headed[0] = math.atan2(vy, vx), True
            return vx, vy, vz
        if mode[0] == PLAN_BACK:
            x, y = np.array([obs.x]), np.array([obs.y])
            vx, vy, arrived = fly_back(bx, by, speed, x, y, self.dt)
            if arrived[0]:
                marks, ids, lx, ly, vx, vy = rx_arrive(self.state, x, y, self.params)
                if marks[0]:
                    self.record(int(ids[0]), obs.t, float(lx[0]), float(ly[0]))
                self._plan = self.tick_plan()
        return float(vx[0]), float(vy[0]), vz

    def tick_plan(self) -> tuple[np.ndarray, ...]:
        """:func:`rx_plan` on this batch of one: (mode, vx, vy, x, y, speed), each (1,)."""
        return rx_plan(self.state, np.array([self.strips is not None]))
