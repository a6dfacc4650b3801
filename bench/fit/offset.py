"""The time-offset scan: does the fit's estimate fit the poses better at t + dt?

Offsets in s on :data:`OFFSET_GRID`; gains in nats on a seeded subsample of rows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .likelihood import Params, rows_from_table
from .eiv import eiv_rows, rule_sigmas
from .parallel import evaluate
from .pilot import vertex_shift
from .result import FitOptions
from .table import Table, gps_scale

#: The time-offset scan (:func:`offset_scan`; a fit of the offset starts from the same
#: grid): offsets tried (s), rows scanned (a seeded subsample: detection, not estimation),
#: and how many nats on them the best offset must gain on 0 before the offset is fitted.
#: The likelihood's gains are inflated by pose errors correlated in time (the sandwich's
#: meat is several times its Hessian), so the threshold comes from emulated campaigns,
#: not a chi-square quantile (docs/calibration.md section 2, "Time offset").
OFFSET_GRID = np.arange(-3.0, 3.0001, 0.25)
OFFSET_ROWS = 2000
OFFSET_GAIN = 40.0


@dataclass
class OffsetScan:
    """The time-offset scan at a fit's estimate: the best offset on :data:`OFFSET_GRID`
    (s; refined by the parabola through its neighbours) and what it gains on 0 (nats, on
    the rows scanned)."""

    offset: float
    gain: float
    rows: int  # rows scanned (a seeded subsample of at most OFFSET_ROWS)


def offset_scan(table: Table, params: Params, options: FitOptions) -> OffsetScan | None:
    """The negative log-likelihood of ``params`` with the poses taken at t + dt, for dt on
    :data:`OFFSET_GRID`, on (at most) OFFSET_ROWS of the errors-in-variables rows, the
    other parameters held. None when the table has fewer than 4 distinct times (no track)."""
    if np.unique(table.t).shape[0] < 4:
        return None
    rows = rows_from_table(table)  # (eiv_rows builds the track, from the positions it uses)
    rows.gps_scale = gps_scale(table)
    n = rows.k.shape[0]
    idx = None
    if n > OFFSET_ROWS:
        rng = np.random.default_rng(np.random.SeedSequence(options.seed, spawn_key=(0x0F5,)))
        idx = np.sort(rng.choice(n, OFFSET_ROWS, replace=False))
    rows, _dropped = eiv_rows(rows, table, rule_sigmas(params, ()), idx, attitude=params.attitude_sigma, track=True)

    def at(dt):  # one likelihood per offset (its own regimes): the points run on the stencil threads
        like = options.likelihood(rows)
        trial = replace(params, time_offset=float(dt))
        like.choose_regimes(trial)
        return like.nll(trial)

    values = np.array(evaluate(at, list(OFFSET_GRID)))
    i = int(np.argmin(values))
    best = float(OFFSET_GRID[i])
    if 0 < i < len(values) - 1:
        best += vertex_shift(values, i, float(OFFSET_GRID[1] - OFFSET_GRID[0]))
    zero = int(np.argmin(np.abs(OFFSET_GRID)))
    return OffsetScan(best, float(values[zero] - values[i]), rows.k.shape[0])

