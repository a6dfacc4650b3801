"""Channel selection (BRIEF 3 step 6): per epoch, the nearest non-outer transmitters.

Units: ``d`` in centimetres, ``delta`` in degrees, ``field`` in scene units in the
receiver frame (body x forward, y left, z up), as :class:`~.types.Measurement` gives them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from emulator.receiver.model.types import ZONE_OUTER, Measurement


@dataclass
class Epochs:
    """Channel-selected receiver output for N epochs: arrays of shape (N, channels).

    Empty slots are (id, d, delta) = (-1, -1, -1), ``field`` the selected transmitter's
    field (zero when empty).
    """

    ids: NDArray[np.int64]
    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    field: NDArray[np.float64] | None = None


def select_channels(meas: Measurement, ids: ArrayLike, channels: int) -> Epochs:
    """Keep the ``channels`` nearest non-outer transmitters per epoch (BRIEF 3 step 6).

    Sorted by (d, id) ascending; ``ids`` (M,) must be sorted ascending so that a stable
    sort on d alone gives the (d, id) order.
    """
    ids = np.asarray(ids, dtype=np.int64)
    n, m = meas.d.shape
    key = np.where(meas.zone == ZONE_OUTER, np.iinfo(np.int64).max, meas.d)
    order = np.argsort(key, axis=1, kind="stable")[:, :channels]
    kept = np.take_along_axis(meas.zone, order, axis=1) != ZONE_OUTER
    width = order.shape[1]
    d, delta = (np.take_along_axis(a, order, axis=1) for a in (meas.d, meas.delta))
    selected = (ids[order], d, delta)
    out_ids, out_d, out_delta = (np.full((n, channels), -1, dtype=np.int64) for _ in selected)
    for out, values in zip((out_ids, out_d, out_delta), selected):
        out[:, :width] = np.where(kept, values, -1)
    fld = None
    if meas.field is not None:
        fld = np.zeros((n, channels, 3))
        fld[:, :width] = np.take_along_axis(meas.field, order[..., None], axis=1)
        fld[out_ids < 0] = 0.0
    return Epochs(out_ids, out_d, out_delta, fld)
