"""The rows the fit uses: those with a direction, and for the errors-in-variables model
the geometry at the expected true receiver poses with each row's pose-error moments.

Sigmas: horizontal and vertical GPS error in m, attitude error in rad per body axis;
positions ENU in m, quaternions [w, x, y, z] body to world.
"""

from __future__ import annotations

import math

import numpy as np

from .likelihood import Params, PoseTrack, Rows, geometry, rows_from_table
from .parallel import pose_moments_halves
from .pose_error import MAX_SD, SIGNAL_PIECE, posterior_attitudes, posterior_positions
from .table import Table, gps_scale

#: pose_sigma under the errors-in-variables model when not given (its lower bound: a
#: larger floor biased r_en by +0.6 % on exact poses in development).
EIV_POSE_SIGMA = 1e-4
#: Where the errors-in-variables rule is first evaluated when the sigmas are fitted
#: (horizontal m, attitude rad); floors for the re-evaluation at the estimate.
EIV_START = (0.5, math.radians(1.0))
EIV_FLOOR = (0.01, math.radians(0.1))


def usable(rows: Rows) -> Rows:
    """Drop rows with the receiver exactly at the transmitter (no direction: no information)."""
    keep = np.isfinite(rows.geo.log_r)
    if keep.all():
        return rows
    return rows.take(keep)


def rule_sigmas(p: Params, free) -> tuple[float, float, float]:
    """Where to evaluate the errors-in-variables rule: at the current sigmas, floored."""
    h = max(p.gps_sigma, EIV_FLOOR[0])
    return (h, p.gps_ratio * h, max(p.attitude_sigma, EIV_FLOOR[1]))


def eiv_rows(
    rows: Rows, table: Table, sigma0, idx=None, attitude: float | None = None, track: bool = False,
    piece: tuple[float, int] = SIGNAL_PIECE,
) -> tuple[Rows, int]:
    """The rows of ``table`` (``rows``: all of them) for the errors-in-variables model at
    sigmas ``sigma0``: geometry at the expected true receiver poses, the pose-error
    moments, and only rows not at the transmitter whose pose-error spread of log d is
    within pose_error.MAX_SD. Returns (rows, number left out for their pose error).
    ``idx``: only these rows (sorted indices; the positions and the time-offset track
    still come from all of them). ``attitude``: the attitude error the tilts are shrunk
    by (default sigma0's, which is floored for the rule; 0 keeps the logged attitudes).
    The time-offset track is built when ``rows`` has one or ``track`` asks for it.
    ``piece``: the likelihood's pieces over this pose error (:attr:`PoseMoments.piece`)."""
    post = posterior_positions(table.rx_pos, table.tx_pos, sigma0[0], sigma0[1])
    quat = posterior_attitudes(table.rx_quat, sigma0[2] if attitude is None else attitude)
    # the geometry at the expected true poses, and so is the time-offset track's (with
    # the logged ones there, any offset but 0 took the shrinkage away: a step in the
    # likelihood at 0 that moved kappa_eq by 1.8 s.e. with the sigmas estimated, 3.4 with
    # them given, when the offset was freed on a 60-minute campaign without one)
    if track or rows.track is not None:
        rows.track = PoseTrack(table, post.pos, quat)
    pos, rx_q, tx_p, tx_q = post.pos, quat, table.tx_pos, table.tx_quat
    if idx is not None:
        rows = rows.take(idx)
        pos, rx_q, tx_p, tx_q = pos[idx], rx_q[idx], tx_p[idx], tx_q[idx]
    rows.geo = geometry(pos, rx_q, tx_p, tx_q)
    rule0 = (sigma0[0], max(sigma0[1] * post.v_factor, 1e-6), sigma0[2])
    rows.moments = mom = pose_moments_halves(pos, rx_q, tx_p, tx_q, rule0)
    mom.piece = piece
    # the likelihood scales the vertical group by gps_ratio * gps_sigma: fold the factor in
    for arr in (mom.m_xy, mom.v_xy, mom.m_3, mom.v_3):
        arr[1] *= post.v_factor**2
    s = np.asarray(sigma0)
    mom = rows.moments
    if rows.gps_scale is None:
        _m, vxy, _m3, v3 = mom.spread(s)
    else:
        w = np.stack([(s[0] * rows.gps_scale) ** 2, (s[1] * rows.gps_scale) ** 2, np.full(rows.k.shape, s[2] ** 2)])
        vxy, v3 = np.einsum("gn,gn->n", w, mom.v_xy), np.einsum("gn,gn->n", w, mom.v_3)
    finite = np.isfinite(rows.geo.log_r)
    keep = finite & (np.maximum(vxy, v3) <= MAX_SD * MAX_SD)
    return rows.take(keep), int(np.sum(finite & ~keep))


def model_rows(table: Table, params: Params) -> Rows:
    """The rows and per-row model the fit used for ``params`` (for the report)."""
    rows = rows_from_table(table)
    if params.gps_sigma > 0 or params.attitude_sigma > 0:
        rows.gps_scale = gps_scale(table)
        return eiv_rows(rows, table, rule_sigmas(params, ()), attitude=params.attitude_sigma)[0]
    return usable(rows)

