"""Many closed-loop runs stepped together: the per-run :class:`ClosedLoop`, batched, with
the same results bit for bit. docs/closed_loop.md, "Many runs at once", describes the
design (one receiver-model call per epoch for all runs, the controllers of a strategy
deciding together on arrays, tick plans) and why the floats agree (CPython's own ``math``
functions element by element, :mod:`emulator.closed_loop.strategy`; numpy's ``cbrt``,
``arctan`` and ``einsum`` per element whatever the array, which IEEE does not promise:
``tests/emulator/closed_loop/test_batch_loop.py`` checks it).

Same frames and units as :mod:`emulator.closed_loop.loop` (world ENU metres, scene
seconds); runs with fewer transmitters are padded with silent ones far away. Not batched
(``ValueError``: use :class:`ClosedLoop`): what :meth:`BatchLoop._check` refuses.
"""

from __future__ import annotations

import math
import time

import numpy as np

from emulator.closed_loop.controllers import (
    PLAN_BACK, PLAN_CONST, PLAN_SEARCH, SEARCH, EpochArrays, FluxFollower, FluxParams, FluxState, RxParams,
    RxState, fly_back, flux_epoch, rx_arrive, rx_epoch, rx_plan, strip_velocity,
)
from emulator.closed_loop.loop import RunResult, control_ticks, make_vehicle, run_result
from emulator.closed_loop.strategy import atan2, exact, hypot
from emulator.closed_loop.vehicle import FlatTerrain
from emulator.receiver.model import measure, select_channels
from emulator.receiver.noise import NoiseEffect, ball_points
from emulator.scene.types import Scene

# The exact Python function, element by element (see the module docstring).
_hypot3 = np.frompyfunc(math.hypot, 3, 1)

#: A padding transmitter sits this far below the origin: its field never leaves the outer zone.
_FAR = -1.0e7


class BatchLoop:
    """Receiver ``index`` of each scene on its vehicle, all stepped together (see the
    module docstring); :meth:`run` returns one :class:`RunResult` per scene, as
    ``ClosedLoop(scene, index, record=False).run(t_max)`` would."""

    #: Epochs of noise normals drawn at a time from each run's stream.
    NOISE_BLOCK = 32

    def __init__(self, scenes: list[Scene], index: int = 0) -> None:
        if not scenes:
            raise ValueError("a batch needs at least one scene")
        self.scenes = list(scenes)
        first = scenes[0]
        self.rate_hz = first.rate_hz
        self.ticks, self.dt = control_ticks(first, index)
        self.channels = first.receivers[index].channels
        self.model = first.receiver_model(index)  # the receiver's class and constants
        self.noise_on = first.effects.noise
        ids = max((s.transmitter_ids for s in scenes), key=len)
        self.ids = np.asarray(ids, dtype=np.int64)
        for s in scenes:
            self._check(s, index)
        n, m = len(scenes), len(self.ids)
        self.m = np.array([len(s.transmitter_ids) for s in scenes])
        self.tx_pos = np.full((n, m, 3), (0.0, 0.0, _FAR))
        self.tx_quat = np.full((n, m, 4), (1.0, 0.0, 0.0, 0.0))
        for j, s in enumerate(scenes):
            for c, tx in enumerate(s.transmitters):
                self.tx_pos[j, c] = tx.trajectory.positions[0]
                self.tx_quat[j, c] = tx.trajectory.orientations[0]
        self.noise = [NoiseEffect(s.seed, index) for s in scenes] if self.noise_on else None
        # Each run's noise normals, NOISE_BLOCK epochs ahead (the same stream: see NoiseEffect).
        self.noise_buf = np.zeros((n, self.NOISE_BLOCK, m, 5)) if self.noise_on else None
        self.noise_used = self.NOISE_BLOCK
        # Vehicles and controllers: the per-run objects, then their state as arrays.
        pairs = [make_vehicle(s, index, self.dt) for s in scenes]
        uavs = [u for u, _ in pairs]
        self.ctrl = [c for _, c in pairs]
        self.sensors = [u.range for u in uavs]
        self.x, self.y, self.z = np.array([u.position for u in uavs]).T.copy()
        self.yaws = np.array([u.yaw for u in uavs], dtype=np.float64)
        self.quat = np.array([u.orientation for u in uavs])
        self.v_max = np.array([u.v_max for u in uavs])
        self.v_z_max = np.array([u.v_z_max for u in uavs])
        specs = [s.receivers[index].vehicle for s in scenes]
        self.k_z = np.array([sp.k_z for sp in specs])
        self.r_s = np.array([sp.r_s for sp in specs])
        self.noisy_range = np.array([u.range.sigma for u in uavs]) > 0
        self.any_noisy_range = bool(self.noisy_range.any())
        self.range_buf = np.zeros((n, uavs[0].range.BLOCK))
        self.range_used = self.range_buf.shape[1]  # readings taken from the current blocks
        self.contacts = np.zeros(n, dtype=np.int64)
        # Terrains: flat ones as an elevation per run, DEMs grouped by object.
        self.terrain = [sp.terrain for sp in specs]
        self.flat = all(isinstance(t, FlatTerrain) for t in self.terrain)
        self.elevation = np.array([t.elevation if isinstance(t, FlatTerrain) else 0.0 for t in self.terrain])
        distinct = {id(t): t for t in self.terrain}
        self.terrains = list(distinct.values())
        group = {key: g for g, key in enumerate(distinct)}
        self.terrain_group = np.array([group[id(t)] for t in self.terrain])
        # Strip search waypoints, padded.
        strips = [c.strips for c in self.ctrl]
        w = max((len(st.waypoints) for st in strips if st is not None), default=0)
        self.wp = np.zeros((n, max(w, 1), 2))
        self.wp_count = np.zeros(n, dtype=np.int64)
        self.wp_next = np.zeros(n, dtype=np.int64)
        for j, st in enumerate(strips):
            if st is not None:
                self.wp[j, : len(st.waypoints)] = st.waypoints
                self.wp_count[j] = len(st.waypoints)
                self.wp_next[j] = st.next
        self.has_strips = np.array([st is not None for st in strips])
        self.sets_heading = np.array([c.search_sets_heading for c in self.ctrl])
        # The controllers decide in numpy, all runs of a strategy together (flux_epoch,
        # rx_epoch: the code each controller object runs on a batch of one); their state
        # lives here, what they located in the controller objects (Controller.record).
        self.is_flux = np.array([isinstance(c, FluxFollower) for c in self.ctrl])
        self.flux = FluxState.empty(n)
        self.flux_par = FluxParams.of(specs)
        self.rx = RxState.empty(n)
        self.rx_par = RxParams.of(specs, self.model)
        self.marked = np.zeros((n, m + 1), dtype=bool)  # by id column; column m: no id
        self.col = np.full(int(self.ids.max()) + 2, m, dtype=np.int64)  # id + 1 -> column
        self.col[self.ids + 1] = np.arange(m)
        self.n_marked = np.zeros(n, dtype=np.int64)
        # Tick plans (filled at each epoch, and when a fine-search line ends).
        self.mode = np.full(n, PLAN_CONST, dtype=np.int8)
        self.pvx, self.pvy, self.bx, self.by, self.bspeed, self.path = np.zeros((6, n))
        self.next_k = 0

    def _check(self, s: Scene, index: int) -> None:
        rx = s.receivers[index]
        spec = rx.vehicle
        why = None
        if spec is None or spec.controller == "external_mavlink":
            why = "a simulated vehicle with an onboard controller"
        elif s.rate_hz != self.rate_hz or control_ticks(s, index) != (self.ticks, self.dt):
            why = "the same rate_hz and control_rate_hz"
        elif rx.channels != self.channels or s.receiver_model(index) != self.model or s.effects.noise != self.noise_on:
            why = "the same channels, receiver model (class, constants) and noise switch"
        elif s.effects.pulses or s.effects.quantize or rx.display:
            why = "no pulses, quantize effect or profile display"
        elif not s.transmitters:
            why = "at least one transmitter"
        elif not all(tx.trajectory.is_static for tx in s.transmitters):
            why = "static transmitters"
        elif list(s.transmitter_ids) != self.ids[: len(s.transmitter_ids)].tolist():
            why = "transmitter ids that are a prefix of the longest run's"
        if why is not None:
            raise ValueError(f"{s.name or 'scene'}: the batch loop needs {why}; use ClosedLoop")

    # -- pieces of one tick, all runs -------------------------------------------------
    def _heights(self, x: np.ndarray, y: np.ndarray, live: np.ndarray) -> np.ndarray:
        if self.flat:
            return self.elevation[live]
        out = np.empty(live.size)
        group = self.terrain_group[live]
        for g, terrain in enumerate(self.terrains):
            r = np.flatnonzero(group == g)
            if r.size:
                out[r] = terrain.heights(x[r], y[r])
        return out

    def _height_reading(self, live: np.ndarray) -> np.ndarray:
        x, y, z = self.x[live], self.y[live], self.z[live]
        value = z - self._heights(x, y, live)
        if self.any_noisy_range:
            if self.range_used == self.range_buf.shape[1]:
                for j in np.flatnonzero(self.noisy_range).tolist():
                    self.range_buf[j] = self.sensors[j].draw_block()
                self.range_used = 0
            noisy = self.noisy_range[live]
            value = np.where(noisy, value + self.range_buf[live, self.range_used], value)
            self.range_used += 1
        return value

    def _search(self, rows: np.ndarray, live: np.ndarray, vx: np.ndarray, vy: np.ndarray) -> None:
        """The strip search (:func:`strip_velocity`) for live[rows], into vx[rows], vy[rows]."""
        j = live[rows]
        nxt = self.wp_next[j]
        vx[rows], vy[rows] = strip_velocity(self.wp[j], self.wp_count[j], nxt, self.x[j], self.y[j], self.v_max[j])
        self.wp_next[j] = nxt
        heads = self.sets_heading[live[rows]]
        if not heads.any():
            return
        head = rows[heads & ((vx[rows] != 0.0) | (vy[rows] != 0.0))]
        if head.size:
            j = live[head]
            self.rx.heading[j], self.rx.headed[j] = exact(atan2, vy[head], vx[head]), True

    def _decide(self, live: np.ndarray, t: float, ep) -> None:
        """The epoch tick: the controllers of the live runs decide on their new epoch
        (each strategy's runs together) and state their tick plans."""
        flux = self.is_flux[live]
        for kind in (flux, ~flux):
            rows = np.flatnonzero(kind)
            if not rows.size:
                continue
            j = live[rows]
            ids = ep.ids[rows]
            marked = self.marked[j[:, None], self.col[ids + 1]]
            field = ep.field[rows] if kind is flux else None
            arrays = EpochArrays(t, self.x[j], self.y[j], self.yaws[j], ids, ep.d[rows], ep.delta[rows], field, marked)
            if kind is flux:
                st = self.flux.take(j)
                marks, located = flux_epoch(st, arrays, self.flux_par.take(j))
                self.flux.put(j, st)
                self._record(j[marks], located, t, self.x[j[marks]], self.y[j[marks]])
                search = st.phase == SEARCH
                self.mode[j] = np.where(search & self.has_strips[j], PLAN_SEARCH, PLAN_CONST)
                self.pvx[j] = np.where(search, 0.0, st.vx)
                self.pvy[j] = np.where(search, 0.0, st.vy)
            else:
                st = self.rx.take(j)
                rx_epoch(st, arrays, self.rx_par.take(j))
                self.rx.put(j, st)
                self._rx_plan(j, st)

    def _rx_plan(self, j: np.ndarray, st: RxState) -> None:
        self.mode[j], self.pvx[j], self.pvy[j], self.bx[j], self.by[j], self.bspeed[j] = rx_plan(st, self.has_strips[j])

    def _record(self, j: np.ndarray, tx_ids: np.ndarray, t: float, x: np.ndarray, y: np.ndarray) -> None:
        """Runs j located tx_ids under (x, y) at time t: marked from now on."""
        for k, tx_id, xk, yk in zip(j.tolist(), tx_ids.tolist(), x.tolist(), y.tolist()):
            self.ctrl[k].record(tx_id, t, xk, yk)
            self.marked[k, self.col[tx_id + 1]] = True
            self.n_marked[k] += 1

    def _step_vehicles(self, live, vx, vy, vz, v_max, v_z_max) -> None:
        """UAV.step for every live run (paper eq. 9); v_max, v_z_max: the live runs'."""
        # |v| > v_max needs the exact math.hypot only where it is not clearly below:
        # sqrt(vx^2 + vy^2) is within a few ulp of it (1e-12 is far beyond that).
        near = np.flatnonzero(~(np.sqrt(vx * vx + vy * vy) < v_max * (1.0 - 1e-12)))
        if near.size:
            speed = exact(hypot, vx[near], vy[near])
            over = speed > v_max[near]
            if over.any():
                o = near[over]
                k = v_max[o] / speed[over]
                vx[o] *= k
                vy[o] *= k
        vz = np.minimum(np.maximum(vz, -v_z_max), v_z_max)
        x = self.x[live] + vx * self.dt
        y = self.y[live] + vy * self.dt
        z = self.z[live] + vz * self.dt
        ground = self._heights(x, y, live)
        below = z < ground
        self.x[live], self.y[live] = x, y
        self.z[live] = np.where(below, ground, z)
        if below.any():
            self.contacts[live[below]] += 1

    # -- one epoch ----------------------------------------------------------------------
    def _measure(self, live: np.ndarray):
        noise = None
        if self.noise is not None:
            if self.noise_used == self.NOISE_BLOCK:
                for j in live.tolist():
                    self.noise_buf[j, :, : self.m[j]] = self.noise[j].normals(self.NOISE_BLOCK, int(self.m[j]))
                self.noise_used = 0
            noise = ball_points(self.noise_buf[live, self.noise_used])
            self.noise_used += 1
        pos = np.stack([self.x[live], self.y[live], self.z[live]], axis=1)
        field = bool(self.is_flux[live].any())  # only flux followers read the field
        meas = measure(pos, self.quat[live], self.tx_pos[live], self.tx_quat[live], self.model, noise=noise, want_field=field)
        return select_channels(meas, self.ids, self.channels)

    def _epoch(self, live: np.ndarray) -> None:
        t_k = self.next_k / self.rate_hz
        ep = self._measure(live)
        self.next_k += 1
        k_z, r_s, v_max, v_z_max = self.k_z[live], self.r_s[live], self.v_max[live], self.v_z_max[live]
        search = back = None  # the rows of each plan mode, while the plans stay
        for i in range(self.ticks):
            t = t_k + i * self.dt
            height = self._height_reading(live)
            vz = k_z * (r_s - height)
            if i == 0:
                self._decide(live, t, ep)
            if search is None:
                mode = self.mode[live]
                search = np.flatnonzero(mode == PLAN_SEARCH)
                back = np.flatnonzero(mode == PLAN_BACK)
            vx, vy = self.pvx[live], self.pvy[live]
            if search.size:
                self._search(search, live, vx, vy)
            if back.size and self._fly_back(back, live, vx, vy, t):
                search = None  # new plans from the next tick on
            self._step_vehicles(live, vx, vy, vz, v_max, v_z_max)

    def _fly_back(self, rows: np.ndarray, live: np.ndarray, vx: np.ndarray, vy: np.ndarray, t: float) -> bool:
        """PLAN_BACK (fine-search lines on their way back) for live[rows]; on arrival the
        controller decides what comes next (rx_arrive) and states a new plan (then
        returns True)."""
        j = live[rows]
        vx[rows], vy[rows], arrived = fly_back(self.bx[j], self.by[j], self.bspeed[j], self.x[j], self.y[j], self.dt)
        if arrived.any():
            a = j[arrived]
            st = self.rx.take(a)
            marks, located, lx, ly, vx[rows[arrived]], vy[rows[arrived]] = rx_arrive(st, self.x[a], self.y[a], self.rx_par.take(a))
            self.rx.put(a, st)
            self._record(a[marks], located, t, lx, ly)
            self._rx_plan(a, st)
            return True
        return False

    # -- whole searches -----------------------------------------------------------------
    def run(self, t_max: float, stop_when_found: bool = True) -> list[RunResult]:
        wall = time.perf_counter()
        n = len(self.scenes)
        k_max = math.ceil(t_max * self.rate_hz)
        t_end = np.zeros(n)
        live = np.arange(n)
        while live.size and self.next_k < k_max:
            last = (self.x[live], self.y[live], self.z[live])
            self._epoch(live)
            step = exact(_hypot3, self.x[live] - last[0], self.y[live] - last[1], self.z[live] - last[2])
            self.path[live] += step
            done = (stop_when_found & (self.n_marked[live] >= self.m[live])) | self._exhausted(live)
            t_end[live] = self.next_k / self.rate_hz
            live = live[~done]
        wall = time.perf_counter() - wall
        return [
            run_result(
                self.scenes[j], self.channels, ([], []), [], located=list(self.ctrl[j].located),
                t_end=float(t_end[j]), exhausted=bool(self._exhausted(np.array([j]))[0]), wall_s=wall / n,
                ground_contacts=int(self.contacts[j]), path_length=float(self.path[j]),
            )
            for j in range(n)
        ]

    def _exhausted(self, rows: np.ndarray) -> np.ndarray:
        """Controller.exhausted: searching, and no strip left."""
        phase = np.where(self.is_flux[rows], self.flux.phase[rows], self.rx.phase[rows])
        return (phase == SEARCH) & self.has_strips[rows] & (self.wp_next[rows] >= self.wp_count[rows])


def run_batch(scenes: list[Scene], t_max: float, index: int = 0, stop_when_found: bool = True) -> list[RunResult]:
    """``[ClosedLoop(s, index, record=False).run(t_max) for s in scenes]``, batched."""
    return BatchLoop(scenes, index).run(t_max, stop_when_found)
