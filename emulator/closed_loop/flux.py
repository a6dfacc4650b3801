"""The paper's flux-line follower (eq. 10) with its height hold, over arrays of runs
(:func:`flux_epoch`) and as a per-run :class:`FluxFollower`; see
emulator.closed_loop.controllers for the law. Positions ENU metres, field in scene units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from emulator.closed_loop.strategy import (
    FOLLOW, SEARCH, Controller, EpochArrays, Observation, StateArrays, cos, exact, hypot, pick_slots,
    power, sin, speed_law,
)
from emulator.closed_loop.vehicle import VehicleSpec

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
class FluxParams(StateArrays):
    """:class:`FluxFollower` constants per run (from its :class:`VehicleSpec`)."""

    v_max: np.ndarray
    k_c: np.ndarray
    v_stop: np.ndarray
    reverse: np.ndarray

    @classmethod
    def of(cls, specs: list[VehicleSpec]) -> "FluxParams":
        return cls(np.array([s.v_max for s in specs], dtype=np.float64), np.array([s.k_c for s in specs], dtype=np.float64),
                   np.array([s.v_stop for s in specs], dtype=np.float64), np.array([s.flux_reverse for s in specs]))


def flux_epoch(st: FluxState, ep: EpochArrays, par: FluxParams) -> tuple[np.ndarray, np.ndarray]:
    """:class:`FluxFollower`'s decision on a new epoch, for B runs at once (the one copy
    of that logic: a single FluxFollower runs it with B = 1). Updates ``st`` in place;
    returns (mask of the runs that located their target now, the ids they located):
    the caller records those (:meth:`Controller.record` without the state part, done here).
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
    rho = exact(power, norm, -1.0 / 3.0)  # proportional to the distance, within a factor 1.26
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
    c, si = exact(cos, ep.yaw[g]), exact(sin, ep.yaw[g])
    vx, vy = s * (c * hx - si * hy), s * (si * hx + c * hy)
    slow = exact(hypot, vx, vy) < par.v_stop[g]
    settled = np.where(slow, st.settled[g] + 1, 0)
    st.vx[g], st.vy[g], st.settled[g] = vx, vy, settled
    marks[g] = settled >= FluxFollower.SETTLE_EPOCHS
    located = st.target[marks]
    st.target[marks], st.phase[marks], st.following[marks] = -1, SEARCH, -1
    st.vx[marks], st.vy[marks], st.settled[marks] = 0.0, 0.0, 0
    return marks, located


class FluxFollower(Controller):
    """The paper's eq. 10 on the full receiver-frame field vector, and ``flux_reverse``
    (not in the paper): docs/closed_loop.md, "Strategies"; the reversal rule's numbers
    are the constants below."""

    SETTLE_EPOCHS = 3
    REVERSE_GROWTH = 1.1
    REVERSE_EVERY = 5

    def __init__(self, spec: VehicleSpec, dt: float | None = None) -> None:
        self.state = FluxState.empty(1)  # this run's state: flux_epoch on a batch of one
        self.params = FluxParams.of([spec])
        super().__init__(spec, dt)

    def command(self, obs: Observation) -> tuple[float, float, float]:
        vz = self.height_hold(obs)
        if obs.new_epoch:
            marks, ids = flux_epoch(self.state, EpochArrays.of(obs, self.marked), self.params)
            if marks[0]:
                self.record(int(ids[0]), obs.t, obs.x, obs.y)
        if self.phase == "search":
            vx, vy = self.search_velocity(obs)
            return vx, vy, vz
        return float(self.state.vx[0]), float(self.state.vy[0]), vz
