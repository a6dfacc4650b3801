"""Search strategies flown in closed loop: velocity commands from receiver output.

Two strategies, both with the paper's height hold V_z = k_z (r_s - y_s) (section IV):

* :class:`FluxFollower` — the paper's flux-line follower, eq. 10, on the full field
  vector ^r h (what a research receiver gives as ``$PARVH``, arva_sim's ``direction``)::

      V_xy = L_xy v_max g / sqrt(1 + g^2) R_r h / |h|,    g = k_c |h|^(-1/3)

  The speed g/sqrt(1+g^2) v_max falls towards 0 as |h| grows near the transmitter; the
  direction is the field in the world frame. Located: |V_xy| < v_stop on three
  consecutive epochs — the drone has settled where the field is vertical, which for a
  horizontal dipole dz below the flight height is dz/sqrt(2) from its ground
  projection (towards its -x end).

* :class:`ReceiverOnlySearch` — only (id, d, delta), the way a rescuer uses a
  commercial receiver: (1) signal search along strips; (2) coarse search: follow the
  flux line by delta (folded to +-90 deg, so the continuation closest to the current
  heading is taken, and the heading is reversed when d grows: "if the distance
  increases, turn around"), slowing down with d by the same law as eq. 10 with
  |h|^(-1/3) replaced by its value (4 pi / kappa_eq)^(1/3) d; (3) fine search in the
  inner zone (delta = 0): bracketing along a line and then across it, at the minimum
  of d each time, twice (the second cross at half speed); located at the last minimum.
  (Details and the escape from the mid zone's "d grows near a steep dipole" trap in
  :class:`ReceiverOnlySearch`.)

Both search for a signal with a lawnmower over ``search_area`` (strips ``strip_width``
apart) when one is given, else they wait for a signal (the paper: "after taking off,
the UAV waits for a valid ARVA signal"). With several transmitters, a located one is
*marked* (its id ignored from then on, as receivers' "mark" function does) and the
search goes on with the nearest unmarked one, or resumes the strips.

Controllers see an :class:`Observation` per control tick: the vehicle's own position and
yaw (its navigation solution), the range-sensor reading, and the latest receiver epoch
(held between epochs; ``new_epoch`` is true on the tick it arrived).

**Written once, over arrays of runs.** The decisions (:func:`flux_epoch`;
:func:`rx_epoch`, :func:`rx_plan`, :func:`fly_back`, :func:`rx_arrive`;
:func:`strip_velocity`) take the state
of B runs as numpy arrays (:class:`FluxState`, :class:`RxState`, one element per run)
and an epoch as arrays (:class:`EpochArrays`). A controller object (what
:class:`~emulator.closed_loop.loop.ClosedLoop` flies) holds the state of one run and
calls them with B = 1; :class:`~emulator.closed_loop.batch.BatchLoop` calls them with all
runs of a strategy. The ``math`` functions numpy does not reproduce bit for bit (hypot,
atan2, cos, sin, pow) are applied element by element with CPython's own, so a run's
decisions do not depend on the batch it is in.
"""

from __future__ import annotations

from emulator.closed_loop.flux import FluxFollower, FluxParams, FluxState, flux_epoch
from emulator.closed_loop.receiver_only import (
    ReceiverOnlySearch,
    RxParams,
    RxState,
    fly_back,
    rx_arrive,
    rx_epoch,
    rx_plan,
)
from emulator.closed_loop.strategy import (
    APPROACH,
    FINE,
    FOLLOW,
    INNER_CM,
    PLAN_BACK,
    PLAN_CONST,
    PLAN_SEARCH,
    SEARCH,
    Controller,
    EpochArrays,
    Located,
    Observation,
    StripSearch,
    TickPlan,
    speed_law,
    strip_velocity,
)
from emulator.closed_loop.vehicle import VehicleSpec
from emulator.receiver.model import ModelParams

__all__ = [
    "APPROACH", "FINE", "FOLLOW", "INNER_CM", "PLAN_BACK", "PLAN_CONST", "PLAN_SEARCH", "SEARCH",
    "Controller", "EpochArrays", "FluxFollower", "FluxParams", "FluxState", "Located", "Observation",
    "ReceiverOnlySearch", "RxParams", "RxState", "StripSearch", "TickPlan", "fly_back", "flux_epoch",
    "make_controller", "rx_arrive", "rx_epoch", "rx_plan", "speed_law", "strip_velocity",
]


def make_controller(spec: VehicleSpec, model: ModelParams = ModelParams()) -> Controller:
    if spec.controller == "flux":
        return FluxFollower(spec, model)
    if spec.controller == "receiver_only":
        return ReceiverOnlySearch(spec, model)
    raise ValueError(f"no onboard controller for {spec.controller!r}")
