"""The rows the likelihood evaluates: outcomes and their geometry.

:class:`Rows` holds each row's outcome (k = d in cm, -1 censored), its :class:`Geometry`
(log of the distance r in m, and g, the receiver-frame field direction, |g| in [1, 2];
ENU world frame, quaternions [w, x, y, z] body to world), the pose-error moments of the
errors-in-variables model and the receiver time (s). :class:`PoseTrack` gives the poses
as splines of time, for a clock offset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from emulator.frames.rotation import rotation_components, unit_quaternion_components, x_axis_components

from .pose_error import PoseMoments
from .table import Table


@dataclass
class Geometry:
    """Per-row log r and receiver-frame field direction g = (gx, gy, gz), |g| in [1, 2]."""

    log_r: NDArray[np.float64]
    g: NDArray[np.float64]  # (3, N)

    @property
    def r(self) -> NDArray[np.float64]:
        return np.exp(self.log_r)


def geometry(rx_pos, rx_quat, tx_pos, tx_quat) -> Geometry:
    """r and g for each row (the emulator's formulas, emulator/receiver/model/reference.py). r = 0 gives log r = -inf."""
    rr = rotation_components(unit_quaternion_components(rx_quat, "rx_q"))  # (3, 3, N)
    m = x_axis_components(unit_quaternion_components(tx_quat, "tx_q"))  # (3, N)
    diff = (np.asarray(rx_pos, float) - np.asarray(tx_pos, float)).T
    r = np.sqrt(np.einsum("in,in->n", diff, diff))
    n = diff / np.where(r > 0, r, 1.0)
    x3 = 3.0 * np.einsum("in,in->n", m, n)
    uw = x3 * n - m
    g = np.einsum("ijn,in->jn", rr, uw)  # R_r^T u_w
    with np.errstate(divide="ignore"):
        log_r = np.log(r)
    return Geometry(log_r, g)


def mounted(geo: Geometry, pitch: float, roll: float) -> Geometry:
    """``geo`` with a constant mounting bias of the receiver (pitch, roll in rad): the log
    holds the attitude of the receiver turned by M = Ry(pitch) Rx(roll) in its body frame
    (logged = true M, body to world), so the true receiver-frame field is g = M g_logged."""
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    m = np.array([[cp, sp * sr, sp * cr], [0.0, cr, -sr], [-sp, cp * sr, cp * cr]])
    return Geometry(geo.log_r, m @ geo.g)


class PoseTrack:
    """Poses as smooth functions of time, to evaluate rows at t + time_offset.

    Positions and (sign-aligned) quaternion components are cubic splines over the unique
    times; rows logged at the same time share a pose. Needs >= 4 distinct times.
    ``rx_pos`` / ``rx_quat``: the receiver poses to use instead of the logged ones (the
    errors-in-variables model's posterior means).
    """

    def __init__(
        self, table: Table, rx_pos: NDArray[np.float64] | None = None, rx_quat: NDArray[np.float64] | None = None
    ) -> None:
        # one pose sample per distinct stamp: the first row logged at it (rows sharing a
        # stamp, several slots of an epoch or a stamp logged twice, share that pose)
        t, first = np.unique(table.t, return_index=True)
        self.t = t
        self.row_t = table.t

        def spline(values):
            return CubicSpline(t, np.asarray(values)[first], axis=0, extrapolate=True)

        def quat_spline(q):
            q = np.array(np.asarray(q)[first])  # (once: the samples, in time order)
            flip = np.cumprod(np.where(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0, -1.0, 1.0))
            q[1:] *= flip[:, None]
            return CubicSpline(t, q, axis=0, extrapolate=True)

        self.rx_p, self.tx_p = spline(table.rx_pos if rx_pos is None else rx_pos), spline(table.tx_pos)
        self.rx_q, self.tx_q = quat_spline(table.rx_quat if rx_quat is None else rx_quat), quat_spline(table.tx_quat)

    def take(self, idx) -> "PoseTrack":
        """The same track, evaluated for the rows ``idx`` only."""
        out = object.__new__(PoseTrack)
        out.__dict__.update(self.__dict__)
        out.row_t = self.row_t[idx]
        return out

    def geometry(self, offset: float) -> Geometry:
        tt = np.clip(self.row_t + offset, self.t[0], self.t[-1])
        return geometry(self.rx_p(tt), self.rx_q(tt), self.tx_p(tt), self.tx_q(tt))


@dataclass
class Rows:
    """Observed outcomes (k = d in cm, -1 censored), their geometry and, for the
    errors-in-variables model, how pose error moves each row (:mod:`.pose_error`;
    ``gps_scale``: a per-row factor on gps_sigma, from the logged HDOP and fix quality)."""

    k: NDArray[np.int64]
    geo: Geometry
    track: PoseTrack | None = None
    moments: PoseMoments | None = None
    gps_scale: NDArray[np.float64] | None = None
    t: NDArray[np.float64] | None = None  # receiver time of each row (s), for the time-block covariance

    def take(self, idx, track: bool = True) -> "Rows":
        """The rows ``idx`` (an index array or a mask), with everything that goes with them."""
        return Rows(
            self.k[idx],
            Geometry(self.geo.log_r[idx], self.geo.g[:, idx]),
            self.track.take(idx) if (track and self.track is not None) else None,
            None if self.moments is None else self.moments.take(idx),
            None if self.gps_scale is None else self.gps_scale[idx],
            None if self.t is None else self.t[idx],
        )


def rows_from_table(table: Table, with_track: bool = False) -> Rows:
    geo = geometry(table.rx_pos, table.rx_quat, table.tx_pos, table.tx_quat)
    track = PoseTrack(table) if with_track else None
    return Rows(table.d.astype(np.int64), geo, track, t=np.asarray(table.t, dtype=np.float64))

