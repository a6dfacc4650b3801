"""The fitted parameters and the optimiser's box.

:class:`Params` holds every model constant the likelihood depends on (lengths in m,
kappa_eq for a transmitter moment s = 1, angles in rad, times in s). The optimiser works
on a vector theta: logs of the positive parameters, q as log(q_y / q_x), time_offset and
height_offset as they are (:data:`LINEAR`); :func:`to_params` / :func:`from_params` map
between the two. :data:`BOUNDS` is the box the search stays in (natural units), with its
first difference steps and largest steps per iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

@dataclass(frozen=True)
class Params:
    """Every model constant the likelihood depends on (s = 1)."""

    kappa_eq: float = 1.542
    r_en: float = 80.0
    q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    r_inner: float = 3.0
    r_outer: float = 50.0
    pose_sigma: float = 0.001
    time_offset: float = 0.0
    antennas: int = 3  # 2: no z antenna, g_z = 0, so "d3" is dxy (emulator/receiver/model/reference.py)
    gps_sigma: float = 0.0  # horizontal GPS error of the receiver pose (m, per axis)
    gps_ratio: float = 1.5  # vertical / horizontal GPS error
    attitude_sigma: float = 0.0  # attitude error of the receiver (rad, per body axis)
    height_offset: float = 0.0  # receiver-above-transmitter height the logs miss (m; common GPS error)
    dropout: float = 0.0  # probability that a row reads -1 whatever the signal (a spurious "nothing heard")
    # heavy-tailed horizontal GPS error: with probability gps_outlier a row's horizontal GPS
    # error is from a wide component, gps_outlier_scale times gps_sigma (0: off)
    gps_outlier: float = 0.0
    gps_outlier_scale: float = 4.0
    # constant mounting bias of the receiver's attitude (rad): the true receiver-frame field
    # is Ry(mount_pitch) Rx(mount_roll) times the logged one (rows.mounted; 0: off)
    mount_pitch: float = 0.0
    mount_roll: float = 0.0

    @property
    def pose_error(self) -> tuple[float, float, float]:
        """(horizontal m, vertical m, attitude rad) of the errors-in-variables model."""
        return (self.gps_sigma, self.gps_ratio * self.gps_sigma, self.attitude_sigma)

    def outlier_components(self) -> tuple["Params", "Params"]:
        """(usual, wide): the two components of the heavy-tailed GPS error, each without it;
        the wide one's horizontal sigma is gps_outlier_scale times larger, its vertical the
        same (gps_ratio divided by the scale)."""
        usual = replace(self, gps_outlier=0.0)
        k = self.gps_outlier_scale
        return usual, replace(usual, gps_sigma=k * self.gps_sigma, gps_ratio=self.gps_ratio / k)


#: Parameters the fit can estimate, with their transform to the optimiser's scale.
FREE_PARAMS = (
    "kappa_eq", "r_en", "q", "r_outer", "time_offset", "pose_sigma", "gps_sigma", "attitude_sigma", "height_offset",
    "dropout", "gps_outlier", "gps_outlier_scale", "mount_pitch", "mount_roll",
)  # fmt: skip
#: Parameters on a linear scale (seconds, metres, radians); the others are fitted in logs.
LINEAR = ("time_offset", "height_offset", "mount_pitch", "mount_roll")


def to_params(base: Params, names: tuple[str, ...], theta: NDArray[np.float64]) -> Params:
    """Map the optimiser's vector (log scale except time_offset; q as log(q_y/q_x))."""
    kw = {}
    for name, v in zip(names, theta):
        if name in LINEAR:
            kw[name] = float(v)
        elif name == "q":
            ratio = math.exp(v)
            kw[name] = (1.0, ratio, 1.0) if ratio <= 1.0 else (1.0 / ratio, 1.0, 1.0)
        else:
            kw[name] = math.exp(v)
    return replace(base, **kw)


def from_params(p: Params, names: tuple[str, ...]) -> NDArray[np.float64]:
    out = []
    for name in names:
        if name in LINEAR:
            out.append(getattr(p, name))
        elif name == "q":
            out.append(math.log(p.q[1] / p.q[0]))
        else:
            out.append(math.log(getattr(p, name)))
    return np.array(out)


#: Optimiser box (natural units); an estimate pinned at an edge has not converged.
BOUNDS = {
    "kappa_eq": (1e-6, 1e6),
    "r_en": (0.5, 1e4),
    "q": (1e-3, 1e3),  # q_y / q_x
    "r_outer": (0.05, 1e4),
    "pose_sigma": (1e-4, 0.5),
    "time_offset": (-30.0, 30.0),
    "height_offset": (-5.0, 5.0),  # m
    # Below 5 mm and 0.05 deg the pose error is lost in the 1 cm rounding: the likelihood
    # is flat there, and Newton crept along it for 60 iterations on exact poses.
    "gps_sigma": (0.005, 30.0),  # m
    "attitude_sigma": (math.radians(0.05), 0.5),  # rad
    # below 1e-5 a spurious -1 is rarer than one per campaign: the likelihood is flat there
    "dropout": (1e-5, 0.5),
    # the share of rows in the wide GPS component: as dropout
    "gps_outlier": (1e-5, 0.95),
    "gps_outlier_scale": (1.5, 30.0),  # wide / usual horizontal GPS sigma
    "mount_pitch": (-0.5, 0.5),  # rad (about +-29 deg)
    "mount_roll": (-0.5, 0.5),
}
#: Parameters that may sit at their lower bound on exact poses (held there, with a note).
MAY_VANISH = ("pose_sigma", "gps_sigma", "attitude_sigma", "dropout", "gps_outlier", "gps_outlier_scale")

def box(free) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    lo = np.array([BOUNDS[n][0] if n in LINEAR else math.log(BOUNDS[n][0]) for n in free])
    hi = np.array([BOUNDS[n][1] if n in LINEAR else math.log(BOUNDS[n][1]) for n in free])
    return lo, hi


#: First difference steps, about a third of a typical standard error (log scale).
INITIAL_STEPS = {
    "kappa_eq": 1e-4,
    "r_en": 1e-3,
    "q": 3e-3,
    "r_outer": 1e-4,
    "pose_sigma": 1e-2,
    "time_offset": 0.05,
    "height_offset": 0.01,
    "gps_sigma": 1e-2,
    "attitude_sigma": 1e-2,
    "dropout": 1e-2,
    "gps_outlier": 1e-2,
    "gps_outlier_scale": 1e-2,
    "mount_pitch": 2e-3,  # rad
    "mount_roll": 2e-3,
}


def initial_steps(free) -> NDArray[np.float64]:
    return np.array([INITIAL_STEPS[n] for n in free])


def caps(free) -> NDArray[np.float64]:
    """Largest step per iteration: log pose_sigma may travel far (exact poses)."""
    return np.array([2.0 if n == "time_offset" else 2.5 if n in MAY_VANISH else 0.5 for n in free])

