"""Search strategies flown in closed loop: velocity commands from receiver output
(docs/closed_loop.md, "Strategies", is the full description). Both hold the height, fly a
lawnmower over ``search_area`` until a signal and *mark* a located transmitter:
:class:`FluxFollower`, the paper's eq. 10 on the receiver-frame field ^r h (``$PARVH``),
V_xy = L_xy v_max g / sqrt(1 + g^2) R_r h / |h| with g = k_c |h|^(-1/3), and
:class:`ReceiverOnlySearch`, on (id, d, delta) only, as a rescuer uses a receiver.

A controller sees an :class:`Observation` per control tick (its own position and yaw, the
range reading, the latest epoch, held between epochs). The decisions are written once,
over arrays of B runs (:class:`FluxState`, :class:`RxState`, :class:`EpochArrays`): a
controller object runs them with B = 1, :class:`~emulator.closed_loop.batch.BatchLoop`
with all runs of a strategy; the ``math`` functions numpy does not reproduce bit for bit
are applied element by element with CPython's own, so a run's decisions do not depend on
the batch it is in.
"""

from __future__ import annotations

from emulator.closed_loop.flux import FluxFollower, FluxParams, FluxState, flux_epoch
from emulator.closed_loop.receiver_only import (
    ReceiverOnlySearch, RxParams, RxState, fly_back, rx_arrive, rx_epoch, rx_plan,
)
from emulator.closed_loop.strategy import (
    APPROACH, FINE, FOLLOW, INNER_CM, PLAN_BACK, PLAN_CONST, PLAN_SEARCH, SEARCH, Controller, EpochArrays, Located,
    Observation, StripSearch, speed_law, strip_velocity,
)
from emulator.closed_loop.vehicle import VehicleSpec
from emulator.receiver.model import ModelParams

__all__ = [  # the strategies' public names, re-exported from flux, receiver_only and strategy
    "APPROACH", "FINE", "FOLLOW", "INNER_CM", "PLAN_BACK", "PLAN_CONST", "PLAN_SEARCH", "SEARCH",
    "Controller", "EpochArrays", "FluxFollower", "FluxParams", "FluxState", "Located", "Observation",
    "ReceiverOnlySearch", "RxParams", "RxState", "StripSearch", "fly_back", "flux_epoch",
    "make_controller", "rx_arrive", "rx_epoch", "rx_plan", "speed_law", "strip_velocity",
]


def make_controller(spec: VehicleSpec, model: ModelParams = ModelParams(),
                    dt: float | None = None) -> Controller:
    if spec.controller == "flux":
        return FluxFollower(spec, dt)
    if spec.controller == "receiver_only":
        return ReceiverOnlySearch(spec, model, dt)
    raise ValueError(f"no onboard controller for {spec.controller!r}")
