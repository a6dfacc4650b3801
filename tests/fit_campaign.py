"""Emulated calibration campaigns: what a field team would log, made by our own emulator.

A receiver is carried at walking pace along radial legs around one buried transmitter:
out along a bearing from ``r_min`` to ``r_max`` (horizontal metres), turn round, back in,
then the next bearing (golden-angle steps, so bearings never repeat). It is held at
``height`` above the snow with a per-leg random hold (heading offset, pitch, roll) plus a
small per-second wobble, so the antennas see the field from many directions. The receiver
outputs one epoch per second (channel 1, one transmitter); rows with d = -1 keep the
transmitter's pose, as the session export writes them.

Rows are produced by :func:`emulator.receiver.model.measure` with :class:`NoiseEffect` noise, so a
campaign is exactly what ``arva-emulate`` would print for that walk (BRIEF 3, 3.2).

:class:`PoseError` makes the *logged* poses differ from the true ones the receiver saw, as
field ground truth does: GPS position error (horizontal and vertical sigma in metres,
white or first-order Gauss-Markov with correlation time ``gps_tau`` s), attitude error
(per body axis, degrees, white or Gauss-Markov) and a constant time offset (the pose
stream logged ``time_offset`` s late: the pose logged at t is the true pose at
t - time_offset). Test support only: not part of the shipped package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from emulator.receiver.noise import NoiseEffect
from emulator.receiver.model import ModelParams, measure

from bench.fit.table import Table

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


@dataclass(frozen=True)
class PoseError:
    """Error of the logged receiver poses (metres, degrees, seconds); zero: exact poses."""

    gps_h: float = 0.0  # horizontal sigma per axis (m)
    gps_v: float = 0.0  # vertical sigma (m)
    gps_tau: float = 0.0  # Gauss-Markov correlation time (s); 0 = white
    attitude_deg: float = 0.0  # sigma of the small rotation about each body axis (deg)
    attitude_tau: float = 0.0  # its correlation time (s); 0 = white
    time_offset: float = 0.0  # pose stream late by this much (s)

    @property
    def exact(self) -> bool:
        return self.gps_h == 0 and self.gps_v == 0 and self.attitude_deg == 0 and self.time_offset == 0


def gauss_markov(t, sigma, tau, rng: np.random.Generator, dims: int):
    """Stationary first-order Gauss-Markov noise (n, dims) with s.d. ``sigma`` (a scalar or
    one per dimension) and correlation exp(-|dt| / tau); tau = 0: white."""
    t = np.asarray(t, dtype=np.float64)
    n = t.shape[0]
    w = rng.standard_normal((n, dims))
    if tau <= 0 or n == 0:
        return w * sigma
    a = np.exp(-np.diff(t, prepend=t[0]) / tau)
    x = np.empty((n, dims))
    x[0] = w[0]
    b = np.sqrt(1.0 - a * a)
    for i in range(1, n):  # a linear recursion; 1e5 steps take ~0.1 s
        x[i] = a[i] * x[i - 1] + b[i] * w[i]
    return x * sigma


def logged_poses(t, true_pos, true_quat, walk_again, err: PoseError, rng: np.random.Generator):
    """The receiver poses a field log would hold for true poses (n, 3), (n, 4);
    ``walk_again(times)`` gives the true poses at other times (for the time offset)."""
    pos, quat = true_pos, true_quat
    if err.time_offset != 0.0:
        pos, quat = walk_again(np.asarray(t) - err.time_offset)
    if err.gps_h > 0 or err.gps_v > 0:
        pos = pos + gauss_markov(t, np.array([err.gps_h, err.gps_h, err.gps_v]), err.gps_tau, rng, 3)
    if err.attitude_deg > 0:
        rotvec = gauss_markov(t, math.radians(err.attitude_deg), err.attitude_tau, rng, 3)
        quat = (Rotation.from_quat(quat, scalar_first=True) * Rotation.from_rotvec(rotvec)).as_quat(scalar_first=True)
    return pos, quat


@dataclass(frozen=True)
class Walk:
    """A walking pattern around the transmitter (metres, seconds, degrees)."""

    r_min: float = 1.0  # closest horizontal approach
    r_max: float = 80.0  # farthest; beyond ~60 m the receiver shows -1
    speed: float = 1.1  # m/s along each radial leg
    height: float = 1.0  # receiver above the snow surface
    depth: float = 1.0  # transmitter below the surface
    heading_sd: float = 35.0  # per-leg hold: heading offset from the walking direction
    tilt_sd: float = 20.0  # per-leg hold: pitch and roll
    wobble_sd: float = 4.0  # per-second wobble on each angle


def walk_poses(t, walk: Walk, rng: np.random.Generator):
    """Receiver positions (n, 3) and quaternions (n, 4) [w, x, y, z] at times ``t`` (s).

    Draws, in order: the first bearing, one hold per leg, one wobble per time. With
    ``wobble_sd = 0`` the path is a smooth function of time within each leg.
    """
    t = np.asarray(t, dtype=np.float64)
    n = t.shape[0]
    span = walk.r_max - walk.r_min
    leg_time = span / walk.speed  # one way
    leg = np.maximum(np.floor(t / leg_time), 0).astype(np.int64)  # 0 out, 1 back, 2 out, ...
    phase = t / leg_time - leg
    outward = leg % 2 == 0
    rho = walk.r_min + span * np.where(outward, phase, 1.0 - phase)
    bearing = (leg // 2) * GOLDEN_ANGLE + rng.uniform(0, 2 * np.pi)
    pos = np.stack([rho * np.cos(bearing), rho * np.sin(bearing), np.full(n, walk.height)], axis=1)
    walking_dir = bearing + np.where(outward, 0.0, np.pi)
    n_legs = int(leg.max()) + 1 if n else 0
    hold = rng.normal(0.0, 1.0, (n_legs, 3)) * np.radians([walk.heading_sd, walk.tilt_sd, walk.tilt_sd])
    wobble = rng.normal(0.0, np.radians(walk.wobble_sd), (n, 3))
    yaw = walking_dir + hold[leg, 0] + wobble[:, 0]
    pitch = hold[leg, 1] + wobble[:, 1]
    roll = hold[leg, 2] + wobble[:, 2]
    # Intrinsic z-y-x (yaw, pitch, roll): body x forward, z up (BRIEF 2).
    quat = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1)).as_quat(scalar_first=True)
    return pos, quat


def emulate_campaign(
    minutes: float,
    params: ModelParams = ModelParams(),
    seed: int = 0,
    walk: Walk = Walk(),
    rate_hz: float = 1.0,
    tx_id: int = 1,
    n_rows: int | None = None,
    pose_error: PoseError = PoseError(),
    error_seed: int | None = None,
) -> Table:
    """The normative table of a campaign of ``minutes`` at ``rate_hz`` (or ``n_rows``).

    The transmitter is buried at (0, 0, -depth) with a random tilt; everything random
    (tilt, bearings, holds, wobble, EMI) comes from ``seed``; ``pose_error`` makes the
    logged receiver poses differ from the true ones (its draws come after all others, so
    the true walk and the readings do not depend on it); ``error_seed``, when given, seeds
    the pose error instead (the same walk and readings with another pose error).
    """
    n = int(round(minutes * 60.0 * rate_hz)) if n_rows is None else int(n_rows)

    def draws(times):  # the same transmitter and walk for any times (same draws)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
        tx_rot = Rotation.from_euler("ZYX", [rng.uniform(0, 360), rng.normal(0, 30), rng.normal(0, 30)], degrees=True)
        return tx_rot.as_quat(scalar_first=True), walk_poses(times, walk, rng)

    tx_p = np.array([0.0, 0.0, -walk.depth])
    t = np.arange(n) / rate_hz
    tx_q, (rx_p, rx_q) = draws(t)
    noise = NoiseEffect(seed).draw(n, 1)
    meas = measure(rx_p, rx_q, tx_p[None], tx_q[None], params, noise=noise)
    if not pose_error.exact:
        err_rng = np.random.default_rng(np.random.SeedSequence(seed if error_seed is None else error_seed, spawn_key=(11,)))
        rx_p, rx_q = logged_poses(t, rx_p, rx_q, lambda times: draws(times)[1], pose_error, err_rng)
    d = meas.d[:, 0]
    delta = meas.delta[:, 0]
    ids = np.where(d == -1, -1, tx_id)
    return Table.from_columns(
        source=f"campaign(minutes={minutes:g}, seed={seed})",
        t=np.arange(n) / rate_hz,
        seq=np.arange(n) % 65536,
        id=ids,
        d=d,
        delta=delta,
        rx_pos=rx_p,
        rx_quat=rx_q,
        tx_pos=np.broadcast_to(tx_p, (n, 3)),
        tx_quat=np.broadcast_to(tx_q, (n, 4)),
    )
