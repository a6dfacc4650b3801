"""The receiver model's constants and the dataclasses at its boundary (BRIEF 3).

Units: lengths in metres, ``d`` in centimetres, ``delta`` in degrees, the field in scene
units (|h| = s / (4 pi r^3) on the dipole's equator, s = ``ModelParams.moment``). Frames
(BRIEF 2): world = local ENU; body x forward, y left, z up; quaternions ``[w, x, y, z]``
rotate body into world; the field is in the receiver (body) frame.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from firmware_proto.errors import InputError

ZONE_INNER, ZONE_MID, ZONE_OUTER = 0, 1, 2
#: Receiver classes the model knows: antennas used for the distance (2: horizontal pair).
ANTENNAS = (2, 3)
MAX_DELTA_DEG = 89
#: Largest magnitude a $PARVH component can carry; fields beyond it (r below ~1e-103 m)
#: saturate here rather than print ``inf``.
FIELD_SATURATION = float(np.finfo(np.float64).max)
#: Coordinates beyond this (~1.1e307) could overflow a difference: a block holding any is
#: scaled by an exact power of two on the general path.
HUGE = 2.0**1020


@dataclass(frozen=True)
class ModelParams:
    """Receiver/transmitter constants (BRIEF 3). Lengths in metres.

    ``moment`` is s = kappa |m| in scene units; ``kappa_eq`` is in the same units (with
    s = 1 the estimate is 0.917 r on the dipole axis, 1.155 r broadside).
    """

    kappa_eq: float = 1.542
    moment: float = 1.0
    r_inner: float = 3.0
    r_outer: float = 50.0
    r_en: float = 80.0
    q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: Receiver class: 3 (d3 in the inner zone, BRIEF 3) or 2 (horizontal antennas only:
    #: dxy in every zone). See emulator.receiver.model.reference.
    antennas: int = 3

    def __post_init__(self) -> None:
        if isinstance(self.antennas, bool) or self.antennas not in ANTENNAS:
            raise InputError(f"receiver.antennas: must be 2 or 3, got {self.antennas!r}")
        for name in ("kappa_eq", "moment", "r_inner", "r_outer", "r_en"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"model.{name}: must be a finite number > 0, got {value!r}")
        if len(self.q) != 3 or not all(isinstance(v, (int, float)) and 0 < v <= 1 for v in self.q):
            raise InputError(f"model.q: must be 3 numbers in (0, 1], got {list(self.q)!r}")
        if not (math.isfinite(self.distance_scale) and self.distance_scale > 0):
            raise InputError("model: kappa_eq / moment must be a finite positive ratio")

    @property
    def distance_scale(self) -> float:
        """cbrt(kappa_eq / s): the d3 of a unit field direction at r = 1 m."""
        return math.cbrt(self.kappa_eq / self.moment)

    @property
    def w_en(self) -> float:
        """Radius of the EMI noise ball, s / (2 pi max(q) r_en^3) (paper eq. 5)."""
        return self.moment / (2.0 * math.pi * max(self.q) * self.r_en**3)

    @property
    def noise_distance(self) -> float:
        """cbrt(kappa_eq / (4 pi w_en)): d3 for a field of magnitude w_en."""
        return math.cbrt(self.kappa_eq / (4.0 * math.pi * self.w_en))


@dataclass
class Measurement:
    """What a receiver computes for each (pose, transmitter) pair, arrays of shape (N, M).

    ``d`` in centimetres and ``delta`` in degrees (int64; -1, -1 in the outer zone);
    ``zone`` is ZONE_INNER / ZONE_MID / ZONE_OUTER; ``field`` (N, M, 3), only when asked
    for, is the receiver-frame field in scene units (saturated at +-FIELD_SATURATION;
    its z component is 0 for a 2-antenna receiver, which has no z antenna).
    """

    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    zone: NDArray[np.int8]
    field: NDArray[np.float64] | None = None


@dataclass
class Batch:
    """One ``measure`` call: its checked inputs and the (N, M) outputs both paths write.

    ``rx_p`` (N, 3) m and ``rx_q`` (N, 4) (finite, not yet normalised) in the world frame;
    ``tx_p`` (M, 3) or, for moving transmitters, (N, M, 3) m; ``tx_m`` the dipole axes,
    component-major: (3, M) or (3, N, M). ``noise`` (N, M, 3) unit-ball points in the
    world frame or None; ``field`` the (N, M, 3) output or None. ``rows``: poses per block
    (about ``chunk`` pairs), ``chunk``: pairs per block of the general path's leftovers.
    """

    params: ModelParams
    rx_p: NDArray[np.float64]
    rx_q: NDArray[np.float64]
    tx_p: NDArray[np.float64]
    tx_m: NDArray[np.float64]
    moving_tx: bool
    noise: NDArray[np.float64] | None
    d: NDArray[np.int64]
    delta: NDArray[np.int64]
    zone: NDArray[np.int8]
    field: NDArray[np.float64] | None
    rows: int
    chunk: int

    @property
    def m(self) -> int:
        return self.d.shape[1]

    @functools.cached_property
    def any_big(self) -> bool:
        """Whether any coordinate exceeds HUGE (found when the general path first asks)."""
        return max(max_abs(self.rx_p), max_abs(self.tx_p)) > HUGE


def max_abs(a: NDArray[np.float64]) -> float:
    """max |a| without an |a| temporary (0 for an empty array)."""
    return max(float(a.max(initial=0.0)), -float(a.min(initial=0.0)))
