"""Closed loop: a receiver on a vehicle, flown by a controller, faster than real time
(docs/closed_loop.md, "The loop").

Per epoch k (scene time t_k = k / rate_hz s, BRIEF 3 step 7) the receiver is evaluated
at the vehicle's pose *now* (the whole effects pipeline of
:class:`~emulator.receiver.receiver.Receiver`), then the controller runs
``control_rate_hz / rate_hz`` ticks of dt = 1 / control_rate_hz with that epoch held,
and the vehicle integrates each velocity command (paper eq. 9). Positions are world ENU
metres. Rendering is sequential, so :class:`ClosedLoop` has a Receiver's
``next_batch(count)`` and is what :class:`~emulator.output.streams.ArvaStream` drives
for a receiver with a ``vehicle``. With ``controller = "external_mavlink"`` each epoch
uses the latest autopilot pose instead (:mod:`emulator.closed_loop.mavlink`).
:meth:`ClosedLoop.run` flies a search experiment and returns a :class:`RunResult`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from emulator.closed_loop.controllers import Controller, Located, Observation, make_controller
from emulator.receiver.model import Epochs
from emulator.receiver.receiver import EpochBatch, Receiver
from emulator.scene.types import Scene
from emulator.closed_loop.vehicle import UAV, VehicleSpec

log = logging.getLogger("arva-emulate")

#: Range-sensor noise draws from this spawn key of the scene seed (receiver noise uses
#: (index,), so the streams never overlap).
RANGE_STREAM = 7


@dataclass
class RunResult:
    """One closed-loop run. Per control tick: ``t`` (s) and ``position`` (T, 3); per
    epoch: ``epoch_t``, ``ids``, ``d``, ``delta`` (K, channels). ``tx_ids`` and
    ``tx_position`` (M, 3) are the transmitters (at t = 0)."""

    t: np.ndarray
    position: np.ndarray
    epoch_t: np.ndarray
    ids: np.ndarray
    d: np.ndarray
    delta: np.ndarray
    located: list[Located]
    tx_ids: np.ndarray
    tx_position: np.ndarray
    t_end: float
    exhausted: bool
    wall_s: float
    ground_contacts: int = 0
    path_length: float = 0.0

    def distance(self, i: int = 0, horizontal: bool = False) -> np.ndarray:
        """Distance (m) from the vehicle to transmitter column ``i`` at every tick."""
        diff = self.position - self.tx_position[i]
        if horizontal:
            return np.hypot(diff[:, 0], diff[:, 1])
        return np.sqrt(np.einsum("ij,ij->i", diff, diff))

    def found(self) -> list[dict]:
        """Per transmitter: was it located, when, and how far (horizontally) from the truth."""
        first: dict[int, Located] = {}
        for ev in self.located:
            first.setdefault(ev.id, ev)
        out = []
        for i, tx_id in enumerate(self.tx_ids.tolist()):
            ev = first.get(tx_id)
            if ev is None:
                out.append({"id": tx_id, "found": False, "t": math.nan, "error_m": math.nan})
            else:
                err = math.hypot(ev.x - self.tx_position[i, 0], ev.y - self.tx_position[i, 1])
                out.append({"id": tx_id, "found": True, "t": ev.t, "error_m": err})
        return out


def run_result(scene: Scene, channels: int, ticks: tuple[list, list], epochs: list, **summary) -> RunResult:
    """A run's :class:`RunResult`: ``ticks`` (times, positions) and ``epochs`` ((t, ids, d,
    delta) each) as recorded (empty lists: not recorded); ``summary`` the other fields
    (``located``, ``t_end``, ``exhausted``, ``wall_s``, ``ground_contacts``, ``path_length``)."""
    column = lambda i: np.array([e[i] for e in epochs], dtype=np.int64).reshape(-1, channels)  # noqa: E731
    return RunResult(
        t=np.array(ticks[0]), position=np.array(ticks[1]).reshape(-1, 3), epoch_t=np.array([e[0] for e in epochs]),
        ids=column(1), d=column(2), delta=column(3), tx_ids=scene.transmitter_ids,
        tx_position=np.array([tx.trajectory.positions[0] for tx in scene.transmitters]).reshape(-1, 3), **summary,
    )


def control_ticks(scene: Scene, index: int = 0) -> tuple[int, float]:
    """(control ticks per epoch, tick length dt in s) of receiver ``index``'s vehicle."""
    ticks = max(1, round(scene.receivers[index].vehicle.control_rate_hz / scene.rate_hz))
    return ticks, 1.0 / (scene.rate_hz * ticks)


def make_vehicle(scene: Scene, index: int, dt: float) -> tuple[UAV, Controller]:
    """The simulated vehicle of receiver ``index`` at its start, with its seeded range
    sensor, and its onboard controller ticking every ``dt`` seconds."""
    spec = scene.receivers[index].vehicle
    rng = np.random.default_rng(np.random.SeedSequence(scene.seed, spawn_key=(index, RANGE_STREAM)))
    uav = UAV(spec.terrain, spec.start, spec.height_start, spec.yaw_deg, spec.v_max, spec.v_z_max, spec.range_sigma_m, rng)
    return uav, make_controller(spec, scene.receiver_model(index), dt)


class ClosedLoop:
    """Receiver ``index`` of ``scene`` on its vehicle (see the module docstring)."""

    def __init__(self, scene: Scene, index: int = 0, record: bool = True) -> None:
        spec: VehicleSpec | None = scene.receivers[index].vehicle
        if spec is None:
            raise ValueError(f"receiver {scene.receivers[index].id} has no vehicle")
        self.scene = scene
        self.receiver = Receiver(scene, index, want_field=True)
        self.channels = self.receiver.channels
        self.research = scene.effects.research_sentences
        self.rate_hz = scene.rate_hz
        self.ticks, self.dt = control_ticks(scene, index)
        self.next_k = 0
        self.record = record
        self._ticks_t: list[float] = []
        self._ticks_p: list[tuple[float, float, float]] = []
        self._epochs: list[tuple[float, list, list, list]] = []
        if spec.controller == "external_mavlink":
            from emulator.closed_loop.mavlink import MavlinkPoseSource

            self.uav = None
            self.controller: Controller | None = None
            self.pose_source = MavlinkPoseSource(spec.mavlink, spec.mavlink_origin, baud=spec.mavlink_baud)
            self._start_pose = scene.receivers[index].trajectory.at([0.0])
            self._last_render: float | None = None
            self._waiting_logged = False
        else:
            self.uav, self.controller = make_vehicle(scene, index, self.dt)
            self.pose_source = None

    # -- one epoch ----------------------------------------------------------------
    def current_pose(self) -> tuple[list[float], list[float]]:
        """The receiver's pose as known now (ENU metres, ``[w, x, y, z]``): the vehicle's
        (the next epoch's pose), or with ``external_mavlink`` the latest MAVLink pose
        extrapolated to now by its velocity (what an epoch rendered now uses, before the
        render lead), the start pose until one has arrived (what the epochs use then)."""
        if self.uav is not None:
            pos, quat = self.uav.position, self.uav.orientation
        else:
            p, q = self._external_at(time.monotonic())
            pos, quat = p[0], q[0]
        return [float(v) for v in pos], [float(v) for v in quat]

    def _external_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The external pose at monotonic time ``t`` (the start pose before any arrived)."""
        pose = self.pose_source.latest() if self.pose_source.started else None
        if pose is None:
            return self._start_pose
        p = pose.extrapolated(t, horizon=2.0 / self.rate_hz)
        return np.array([p]), np.array([pose.orientation])

    def _external_pose(self) -> tuple[np.ndarray, np.ndarray]:
        src = self.pose_source
        if not src.started:
            src.start()
        now = time.monotonic()
        # The scheduler renders an epoch one period ahead of its deadline (right after
        # writing the previous one), so in real time the pose is extrapolated by the
        # autopilot's velocity over the interval between our renders; back-to-back
        # renders (as fast as possible) extrapolate nothing.
        lead = 0.0 if self._last_render is None else min(now - self._last_render, 2.0 / self.rate_hz)
        self._last_render = now
        if src.latest() is None and not self._waiting_logged:
            log.warning("%s: no MAVLink pose yet; epochs use the start pose", src.url)
            self._waiting_logged = True
        return self._external_at(now + lead)

    def step(self) -> Epochs:
        """Evaluate epoch ``next_k`` at the current pose, then fly until the next one."""
        t_k = self.next_k / self.rate_hz
        uav = self.uav
        if uav is None:
            pos, quat = self._external_pose()
        else:
            pos = np.array([uav.position])
            quat = np.array([uav.orientation])
        ep = self.receiver.evaluate_poses(np.array([t_k]), pos, quat)
        self.next_k += 1
        if uav is None:
            return ep
        ids, d, delta = ep.ids[0].tolist(), ep.d[0].tolist(), ep.delta[0].tolist()
        fld = ep.field[0].tolist()
        if self.record:
            self._epochs.append((t_k, ids, d, delta))
        ctrl, dt = self.controller, self.dt
        for i in range(self.ticks):
            t = t_k + i * dt
            if self.record:
                self._ticks_t.append(t)
                self._ticks_p.append(uav.position)
            obs = Observation(t, uav.x, uav.y, uav.z, uav.yaw, uav.height_reading(), ids, d, delta, fld, i == 0)
            vx, vy, vz = ctrl.command(obs)
            uav.step(vx, vy, vz, dt)
        return ep

    def next_batch(self, count: int) -> EpochBatch:
        """The Receiver interface: epochs ``next_k .. next_k + count - 1``, in order."""
        k0 = self.next_k
        eps = [self.step() for _ in range(count)]
        fld = np.concatenate([e.field for e in eps]) if self.research else None
        cat = lambda name: np.concatenate([getattr(e, name) for e in eps])  # noqa: E731
        epochs = Epochs(cat("ids"), cat("d"), cat("delta"), fld)
        return EpochBatch(k0, (k0 + np.arange(count, dtype=np.float64)) / self.rate_hz, epochs)

    # -- a whole search -------------------------------------------------------------
    def run(self, t_max: float, stop_when_found: bool = True) -> RunResult:
        """Fly until every transmitter is located (``stop_when_found``), the controller has
        nothing left to search, or scene time ``t_max``."""
        if self.uav is None:
            raise ValueError("run() needs a simulated vehicle (not external_mavlink)")
        wall = time.perf_counter()
        want = set(self.scene.transmitter_ids.tolist())
        k_max = math.ceil(t_max * self.rate_hz)
        path = 0.0
        last = self.uav.position
        while self.next_k < k_max:
            self.step()
            p = self.uav.position
            path += math.dist(p, last)
            last = p
            if (stop_when_found and want <= self.controller.marked) or self.controller.exhausted:
                break
        return run_result(
            self.scene, self.channels, (self._ticks_t, self._ticks_p), self._epochs,
            located=list(self.controller.located), t_end=self.next_k / self.rate_hz,
            exhausted=self.controller.exhausted, wall_s=time.perf_counter() - wall,
            ground_contacts=self.uav.ground_contacts, path_length=path,
        )

    def close(self) -> None:
        if self.pose_source is not None:
            self.pose_source.close()
