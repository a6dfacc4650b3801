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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from emulator.receiver.noise import NoiseEffect
from emulator.receiver.model import ModelParams, measure

from .table import Table

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


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
) -> Table:
    """The normative table of a campaign of ``minutes`` at ``rate_hz`` (or ``n_rows``).

    The transmitter is buried at (0, 0, -depth) with a random tilt; everything random
    (tilt, bearings, holds, wobble, EMI) comes from ``seed``.
    """
    n = int(round(minutes * 60.0 * rate_hz)) if n_rows is None else int(n_rows)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
    tx_rot = Rotation.from_euler("ZYX", [rng.uniform(0, 360), rng.normal(0, 30), rng.normal(0, 30)], degrees=True)
    tx_q = tx_rot.as_quat(scalar_first=True)
    tx_p = np.array([0.0, 0.0, -walk.depth])
    rx_p, rx_q = walk_poses(np.arange(n) / rate_hz, walk, rng)
    noise = NoiseEffect(seed).draw(n, 1)
    meas = measure(rx_p, rx_q, tx_p[None], tx_q[None], params, noise=noise)
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
