"""The ranges a scene's values may take, derived from what the model and protocol carry.

A scene that validates must run: no reading the encoder refuses, no division by zero, no
overflow, no loop without end (issue 16). Each limit below says which of these it rules
out; ``docs/emulator.md`` lists them for users. Units: metres, seconds, Hz.

* Readings. The receiver reports ``d`` = 100 * d3 in the inner zone (d3 <= r_inner) and
  100 * dxy in the mid zone (dxy <= r_outer), rounded half away from zero; the protocol
  carries 0 .. 9,999,999 cm (``firmware_proto.sentences.MAX_D_CM``). So ``r_inner`` and
  ``r_outer`` are at most :data:`MAX_READING_M` = 99,999.99 m and *every* reading fits,
  whatever ``kappa_eq``, the moment or the poses (a larger estimate is the outer zone).
* Noise. ``w_en = s / (2 pi max(q) r_en^3)`` and ``cbrt(kappa_eq / (4 pi w_en))`` must be
  finite and non-zero: ``r_en`` in :data:`R_EN_LIMITS_M`, ``kappa_eq`` and ``moment`` in
  :data:`STRENGTH_LIMITS`, ``q`` in [:data:`MIN_Q`, 1] keep every intermediate within
  about 1e-60 .. 1e60 (r_en = 1e-300 or 1e300 used to end in ZeroDivisionError /
  OverflowError).
* Vehicles (closed loop). The loop takes ``control_rate_hz / rate_hz`` control steps per
  epoch: at most :data:`MAX_CONTROL_STEPS_PER_EPOCH` (1e308 Hz used to loop for ever).
  Speeds, gains and coordinates have physical limits (:data:`VEHICLE_LIMITS`) so a
  position can never leave the float range (v_max = 1e308 reached inf in one step).
"""

from __future__ import annotations

from firmware_proto.sentences import MAX_D_CM

#: Largest distance a reading can carry: 9,999,999 cm.
MAX_READING_M = MAX_D_CM / 100.0

#: (lo, hi) of the model's lengths and strengths.
R_ZONE_LIMITS_M = (1e-6, MAX_READING_M)  # r_inner, r_outer
R_EN_LIMITS_M = (1e-6, 1e9)
STRENGTH_LIMITS = (1e-30, 1e30)  # kappa_eq, moment (scene units)
MIN_Q = 1e-6

MODEL_LIMITS: dict[str, tuple[float, float]] = {
    "r_inner": R_ZONE_LIMITS_M,
    "r_outer": R_ZONE_LIMITS_M,
    "r_en": R_EN_LIMITS_M,
    "kappa_eq": STRENGTH_LIMITS,
    "moment": STRENGTH_LIMITS,
}

#: Shortest step between two waypoint times (s): interpolation divides by it (0, 5e-324
#: overflowed).
MIN_WAYPOINT_DT_S = 1e-6

#: Control steps per epoch a closed loop may take (control_rate_hz / rate_hz).
MAX_CONTROL_STEPS_PER_EPOCH = 1000

#: Coordinates of a vehicle's start, search area and terrain origin: +-1000 km.
MAX_VEHICLE_COORD_M = 1e6

#: receiver.vehicle numbers: (lo, hi); lo 0 means "> 0" for keys that must be positive.
VEHICLE_LIMITS: dict[str, tuple[float, float]] = {
    "v_max": (0.0, 100.0),  # m/s
    "v_z_max": (0.0, 100.0),
    "v_stop": (0.0, 100.0),
    "v_fine": (0.0, 100.0),
    "r_s": (0.0, 1e4),  # m
    "strip_width": (0.0, 1e5),
    "k_c": (0.0, 1e4),
    "k_z": (0.0, 1e4),
    "control_rate_hz": (0.0, 1e4),
    "range_sigma_m": (0.0, 1e4),
    "start_height": (0.0, 1e4),
    "terrain_height": (-1e4, 1e4),
    "yaw": (-1e6, 1e6),  # degrees
}

