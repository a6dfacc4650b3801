"""Independent calibration campaigns for the validation study (issue 28, item 7).

Written apart from the fit and from ``tests/fit_campaign.py`` on purpose: it imports
nothing of ours (numpy and scipy only), transcribes the receiver model from BRIEF
sections 3 and 3.2 itself, and has its own walks, pose-error models and junk, so a
number it confirms is not our own generator agreeing with our own fit.

Units and frames: local ENU metres (BRIEF 2), seconds, quaternions [w, x, y, z]
rotating body vectors into the world; angles in degrees where a name says ``deg``.
One transmitter, buried at (0, 0, -depth) with a random orientation; one receiver
epoch per second on one channel; rows with d = -1 keep the transmitter's pose, with
id = -1, as the session export writes them.

Walk shapes (horizontal distances from the transmitter, metres):

* ``radial``: out and back along random bearings between 2 and 50 m, the receiver
  held with a per-leg heading offset and +-20 deg tilts (like a hand-held search).
* ``level_rw``: a level receiver carried at 1 m/s, its heading a random walk, kept
  between 2 and 50 m (it turns back at the edges); yaw along the track.
* ``spiral``: an Archimedean spiral from 50 m in to 2 m and out again, level.
* ``near``: ``level_rw`` held to 5-15 m.   ``far``: ``level_rw`` held to 30-60 m.
* ``drone``: a lawn-mower pattern 5 m above the snow over 120 m x 120 m at 3 m/s,
  lines 8 m apart, level, yaw along the lines.

Pose-error models (what the log holds instead of the true pose):

* ``exact``: none.
* ``gm``: Gauss-Markov GPS, 1 m horizontal and 1.5 m vertical per axis, tau 30 s;
  Gauss-Markov attitude 2 deg per axis, tau 5 s (``-att05`` and ``-att5`` conditions: 0.5 and
  5 deg, to test the fit's rule that holds an undetermined attitude error at 2 deg).
* ``heavy``: ``gm`` plus multipath jumps: on average one every 2 minutes, a
  horizontal offset of 3-5 m in a random direction lasting 10-60 s.
* ``student``: ``gm`` whose horizontal innovations are Student-t with 3 degrees of
  freedom (scaled to the same 1 m standard deviation).
* ``mount``: ``gm`` plus a constant mounting bias, pitch +3 deg and roll -2 deg.
* ``offset``: ``gm`` plus a clock offset: the pose stream is 0.4 s late.

Junk (applied to the logged rows, after the pose error):

* ``dup``: 1 % of epochs logged twice (same t, seq and values).
* ``gaps``: three gaps of 30-120 s without rows.
* ``spurious``: 2 % of the heard rows turned into "nothing heard" (d = -1).

Everything is drawn from ``numpy.random.SeedSequence(seed, spawn_key=(k,))`` streams, one
per purpose, so a campaign is a pure function of (condition, seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

HEADER = (
    "t,seq,id,d,delta,rx_x,rx_y,rx_z,rx_qw,rx_qx,rx_qy,rx_qz,tx_x,tx_y,tx_z,tx_qw,tx_qx,tx_qy,tx_qz"
)
WALKS = ("radial", "level_rw", "spiral", "near", "far", "drone")
ERRORS = ("exact", "gm", "heavy", "student", "mount", "offset")
JUNK = ("dup", "gaps", "spurious")


@dataclass(frozen=True)
class Truth:
    """The hidden receiver model of one campaign (BRIEF 3; r_inner, r_outer in m)."""

    kappa_eq: float
    r_en: float
    r_inner: float = 3.0
    r_outer: float = 50.0


@dataclass(frozen=True)
class Condition:
    name: str
    walk: str
    error: str = "exact"
    junk: tuple[str, ...] = ()
    minutes: float = 60.0
    #: the attitude error's s.d. per axis (deg) of every error but ``exact``: 2, a consumer
    #: IMU's grade, which the fit's held_attitude rule holds it at; other values test that rule
    attitude_deg: float = 2.0


@dataclass
class Campaign:
    """Logged rows (n, 19) in HEADER order, and the truth behind them."""

    rows: np.ndarray
    truth: Truth
    heard: int  # rows with d >= 0

    def csv_text(self) -> str:
        lines = [HEADER]
        for r in self.rows:
            head = f"{r[0]:.3f},{int(r[1])},{int(r[2])},{int(r[3])},{int(r[4])},"
            lines.append(head + ",".join(f"{v:.9g}" for v in r[5:]))
        return "\n".join(lines) + "\n"


def _rng(seed: int, k: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))


def quat_wxyz(rot: Rotation) -> np.ndarray:
    return rot.as_quat(scalar_first=True)


# --- the receiver model, transcribed from BRIEF 3 and 3.2 ---------------------------------


def round_half_away(x: np.ndarray) -> np.ndarray:
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


def receiver_model(rx_p, rx_q, tx_p, tx_q, truth: Truth, noise_w=None):
    """(d cm, delta deg) integer arrays for n receiver poses and one transmitter each.

    ``noise_w`` (n, 3): the EMI vector w in the world frame (BRIEF 3.2, q = 1, 1, 1)."""
    r_rx = Rotation.from_quat(rx_q, scalar_first=True)
    r_tx = Rotation.from_quat(tx_q, scalar_first=True)
    p = r_tx.inv().apply(rx_p - tx_p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = np.sqrt(x * x + y * y + z * z)
    s = 1.0
    ht = (s / (4 * np.pi * r**5))[:, None] * np.stack([2 * x * x - y * y - z * z, 3 * x * y, 3 * x * z], axis=1)
    h_world = r_tx.apply(ht)
    if noise_w is not None:
        h_world = h_world + noise_w
    h = r_rx.inv().apply(h_world)
    mag = np.sqrt((h * h).sum(axis=1))
    mag_xy = np.hypot(h[:, 0], h[:, 1])
    d3 = np.cbrt(truth.kappa_eq / (4 * np.pi * mag))
    with np.errstate(divide="ignore"):
        dxy = np.cbrt(truth.kappa_eq / (4 * np.pi * mag_xy))
    d = np.full(len(r), -1, dtype=np.int64)
    delta = np.full(len(r), -1, dtype=np.int64)
    inner = d3 <= truth.r_inner
    mid = ~inner & (mag_xy > 0) & (dxy <= truth.r_outer)
    d[inner] = round_half_away(100 * d3[inner]).astype(np.int64)
    delta[inner] = 0
    d[mid] = round_half_away(100 * dxy[mid]).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ang = np.where(h[:, 0] == 0, np.sign(h[:, 1]) * 90.0, np.degrees(np.arctan(h[:, 1] / h[:, 0])))
    delta[mid] = np.clip(round_half_away(ang[mid]), -89, 89).astype(np.int64)
    return d, delta


def ball_noise(n: int, truth: Truth, rng: np.random.Generator) -> np.ndarray:
    """w uniform in the ball of radius s / (2 pi r_en^3) (BRIEF 3.2, s = 1, max q = 1)."""
    radius = 1.0 / (2 * np.pi * truth.r_en**3)
    v = rng.standard_normal((n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    return v * (radius * np.cbrt(rng.uniform(0.0, 1.0, n)))[:, None]


# --- walks ---------------------------------------------------------------------------------

FINE_HZ = 10.0  # walks are drawn on this grid, then sampled (and shifted) by interpolation


def _keep_in_annulus(n, speed, dt, r_lo, r_hi, turn_sd_deg, rng, start_r=None):
    """A correlated random walk (x, y, heading) kept between r_lo and r_hi."""
    pos = np.empty((n, 2))
    hdg = np.empty(n)
    r0 = start_r if start_r is not None else rng.uniform(r_lo, r_hi)
    b0 = rng.uniform(0, 2 * np.pi)
    pos[0] = (r0 * math.cos(b0), r0 * math.sin(b0))
    hdg[0] = rng.uniform(0, 2 * np.pi)
    turns = rng.normal(0.0, math.radians(turn_sd_deg) * math.sqrt(dt), n)
    for i in range(1, n):
        h = hdg[i - 1] + turns[i]
        px, py = pos[i - 1]
        rr = math.hypot(px, py)
        outward = math.atan2(py, px)
        # steer back when out of the band: turn toward the band's middle by up to 30 deg/s
        if rr > r_hi or rr < r_lo:
            want = outward + (math.pi if rr > r_hi else 0.0)
            diff = (want - h + math.pi) % (2 * math.pi) - math.pi
            h += max(-math.radians(30) * dt, min(math.radians(30) * dt, diff))
        hdg[i] = h
        pos[i] = (px + speed * dt * math.cos(h), py + speed * dt * math.sin(h))
    return pos, hdg


def walk_fine(walk: str, seconds: float, rng: np.random.Generator):
    """True receiver poses on the fine grid: times (m,), positions (m, 3), Rotation."""
    dt = 1.0 / FINE_HZ
    m = int(math.ceil(seconds * FINE_HZ)) + int(2 * FINE_HZ) + 1  # margin for the clock offset
    t = np.arange(m) * dt - FINE_HZ * dt  # starts 1 s early
    height = 1.0
    pitch = np.zeros(m)
    roll = np.zeros(m)
    if walk in ("level_rw", "near", "far"):
        lo, hi = {"level_rw": (2.0, 50.0), "near": (5.0, 15.0), "far": (30.0, 60.0)}[walk]
        xy, yaw = _keep_in_annulus(m, 1.0, dt, lo, hi, 12.0, rng)
    elif walk == "radial":
        speed = 1.0
        lo, hi = 2.0, 50.0
        leg_s = (hi - lo) / speed
        leg = np.floor((t - t[0]) / leg_s).astype(int)
        phase = (t - t[0]) / leg_s - leg
        out = leg % 2 == 0
        rho = lo + (hi - lo) * np.where(out, phase, 1 - phase)
        n_legs = leg.max() + 1
        bearing_leg = rng.uniform(0, 2 * np.pi, n_legs // 2 + 1)
        bearing = bearing_leg[leg // 2]
        xy = np.stack([rho * np.cos(bearing), rho * np.sin(bearing)], axis=1)
        hold = rng.normal(0, 1, (n_legs, 3)) * np.radians([30.0, 20.0, 20.0])
        yaw = bearing + np.where(out, 0.0, np.pi) + hold[leg, 0]
        pitch, roll = hold[leg, 1], hold[leg, 2]
    elif walk == "spiral":
        # r goes 50 -> 2 -> 50 ... with the arc speed ~1 m/s and 6 m between turns
        b = 6.0 / (2 * np.pi)
        lo, hi = 2.0, 50.0
        sweep = (hi * hi - lo * lo) / (2 * b)  # path length of one in-or-out pass (approx)
        s = (t - t[0]) * 1.0
        k = np.floor(s / sweep).astype(int)
        f = s / sweep - k
        inward = k % 2 == 0
        rr = np.sqrt(np.where(inward, hi * hi - f * (hi * hi - lo * lo), lo * lo + f * (hi * hi - lo * lo)))
        ang = rr / b + rng.uniform(0, 2 * np.pi)
        xy = np.stack([rr * np.cos(ang), rr * np.sin(ang)], axis=1)
        vel = np.gradient(xy, dt, axis=0)
        yaw = np.arctan2(vel[:, 1], vel[:, 0])
    elif walk == "drone":
        height = 5.0
        speed, width, gap = 3.0, 120.0, 8.0
        line_s = width / speed
        s = t - t[0]
        line = np.floor(s / line_s).astype(int)
        f = s / line_s - line
        n_lines = int(width / gap) + 1
        row = line % (2 * n_lines)
        row = np.where(row < n_lines, row, 2 * n_lines - 1 - row)
        fwd = line % 2 == 0
        x = -width / 2 + width * np.where(fwd, f, 1 - f)
        y = -width / 2 + gap * row
        off = rng.uniform(-gap / 2, gap / 2, 2)
        xy = np.stack([x + off[0], y + off[1]], axis=1)
        yaw = np.where(fwd, 0.0, np.pi) + rng.uniform(-0.1, 0.1)
    else:
        raise ValueError(f"unknown walk {walk!r}")
    if walk != "radial":  # a small per-step wobble even on a level carry
        wob = np.radians(1.0)
        pitch = pitch + rng.normal(0, wob, m)
        roll = roll + rng.normal(0, wob, m)
    pos = np.column_stack([xy, np.full(m, height)])
    rot = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    return t, pos, rot


def sample(t_fine, pos_fine, rot_fine, times):
    """Poses at ``times``: positions linearly interpolated, orientations by slerp."""
    pos = np.column_stack([np.interp(times, t_fine, pos_fine[:, i]) for i in range(3)])
    return pos, Slerp(t_fine, rot_fine)(times)


# --- pose error ------------------------------------------------------------------------------


def gauss_markov(n, dt, sigma, tau, rng, dims, innovations=None):
    """Stationary first-order Gauss-Markov (n, dims), s.d. ``sigma``, correlation exp(-dt/tau)."""
    w = rng.standard_normal((n, dims)) if innovations is None else innovations
    a = math.exp(-dt / tau)
    b = math.sqrt(1 - a * a)
    x = np.empty((n, dims))
    x[0] = w[0]
    for i in range(1, n):
        x[i] = a * x[i - 1] + b * w[i]
    return x * sigma


#: The ``mount`` error's bias (pitch, roll; deg): logged attitude = true * Ry(pitch) Rx(roll).
MOUNT_DEG = (3.0, -2.0)


def pose_error(kind: str, t, pos, rot, fine, rng: np.random.Generator, attitude_deg: float):
    """Logged (positions, Rotation) for true ones at 1 Hz times ``t`` (``attitude_deg``: the
    attitude error's s.d. per axis, :attr:`Condition.attitude_deg`)."""
    if kind == "exact":
        return pos, rot
    if kind == "offset":  # the pose stream 0.4 s late: the pose logged at t is the truth at t - 0.4
        pos, rot = sample(*fine, t - 0.4)
    n = len(t)
    dt = 1.0
    if kind == "student":
        nu = 3.0
        inn = rng.standard_t(nu, (n, 2)) / math.sqrt(nu / (nu - 2))
        horiz = gauss_markov(n, dt, 1.0, 30.0, rng, 2, innovations=inn)
    else:
        horiz = gauss_markov(n, dt, 1.0, 30.0, rng, 2)
    vert = gauss_markov(n, dt, 1.5, 30.0, rng, 1)
    err = np.column_stack([horiz, vert])
    if kind == "heavy":
        k = 0
        while k < n:
            k += int(rng.exponential(120.0)) + 1
            if k >= n:
                break
            length = int(rng.uniform(10, 60))
            mag = rng.uniform(3.0, 5.0)
            ang = rng.uniform(0, 2 * np.pi)
            err[k : k + length, 0] += mag * math.cos(ang)
            err[k : k + length, 1] += mag * math.sin(ang)
            k += length
    att = Rotation.from_rotvec(gauss_markov(n, dt, math.radians(attitude_deg), 5.0, rng, 3))
    logged_rot = rot * att  # a body-frame error rotation
    if kind == "mount":
        logged_rot = logged_rot * Rotation.from_euler("ZYX", [0.0, *MOUNT_DEG], degrees=True)
    return pos + err, logged_rot


# --- campaigns ---------------------------------------------------------------------------------


def draw_truth(seed: int) -> Truth:
    rng = _rng(seed, 1)
    return Truth(kappa_eq=float(rng.uniform(1.3, 1.8)), r_en=float(rng.uniform(60.0, 120.0)))


def campaign(cond: Condition, seed: int) -> Campaign:
    truth = draw_truth(seed)
    seconds = cond.minutes * 60.0
    t = np.arange(int(round(seconds)), dtype=np.float64)
    n = len(t)
    fine = walk_fine(cond.walk, seconds, _rng(seed, 2))
    pos, rot = sample(*fine, t)
    trng = _rng(seed, 3)
    depth = trng.uniform(0.5, 2.0)
    tx_p = np.array([0.0, 0.0, -depth])
    tx_rot = Rotation.from_euler("ZYX", [trng.uniform(0, 360), trng.normal(0, 25), trng.normal(0, 25)], degrees=True)
    tx_q = quat_wxyz(tx_rot)
    tx_pos = np.broadcast_to(tx_p, (n, 3))
    tx_quat = np.broadcast_to(tx_q, (n, 4))
    w = ball_noise(n, truth, _rng(seed, 4))
    d, delta = receiver_model(pos, quat_wxyz(rot), tx_pos, tx_quat, truth, noise_w=w)
    lpos, lrot = pose_error(cond.error, t, pos, rot, fine, _rng(seed, 5), cond.attitude_deg)
    lq = quat_wxyz(lrot)
    seq = np.arange(n) % 65536
    ids = np.where(d >= 0, 1, -1)
    rows = np.column_stack([t, seq, ids, d, delta, lpos, lq, tx_pos, tx_quat])
    jrng = _rng(seed, 6)
    if "spurious" in cond.junk:
        heard = np.flatnonzero(rows[:, 3] >= 0)
        pick = jrng.choice(heard, size=int(round(0.02 * len(heard))), replace=False)
        rows[pick, 2:5] = -1
    if "gaps" in cond.junk:
        keep = np.ones(len(rows), dtype=bool)
        for _ in range(3):
            length = int(jrng.uniform(30, 120))
            start = int(jrng.uniform(0, len(rows) - length))
            keep[start : start + length] = False
        rows = rows[keep]
    if "dup" in cond.junk:
        pick = np.sort(jrng.choice(len(rows), size=max(1, int(round(0.01 * len(rows)))), replace=False))
        rows = np.insert(rows, pick + 1, rows[pick], axis=0)
    return Campaign(rows=rows, truth=truth, heard=int((rows[:, 3] >= 0).sum()))


CONDITIONS = {
    c.name: c
    for c in (
        Condition("radial-exact", "radial"),
        Condition("radial-gm", "radial", "gm"),
        Condition("level-exact", "level_rw"),
        Condition("level-gm", "level_rw", "gm"),
        Condition("level-gm-att05", "level_rw", "gm", attitude_deg=0.5),
        Condition("level-gm-att5", "level_rw", "gm", attitude_deg=5.0),
        Condition("level-heavy", "level_rw", "heavy"),
        Condition("level-student", "level_rw", "student"),
        Condition("level-mount", "level_rw", "mount"),
        Condition("level-offset", "level_rw", "offset"),
        Condition("level-gm-junk", "level_rw", "gm", ("dup", "gaps", "spurious")),
        Condition("spiral-gm", "spiral", "gm"),
        Condition("near-gm", "near", "gm"),
        Condition("far-exact", "far"),
        Condition("far-gm", "far", "gm"),
        Condition("drone-gm", "drone", "gm"),
        Condition("radial-gm-4h", "radial", "gm", minutes=240.0),
    )
}
