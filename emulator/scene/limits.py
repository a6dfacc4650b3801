"""The ranges a scene's values may take, derived from what the model and protocol carry.

A scene that validates must run: no reading the encoder refuses, no division by zero, no
overflow, no loop without end (issue 16). Each limit below says which of these it rules
out; docs/emulator.md "Limits: what a scene may ask for" lists them for users with the
reasons. Units: metres, seconds, Hz.
"""

from __future__ import annotations

from firmware_proto.sentences import MAX_D_CM

#: Largest distance a reading can carry: 9,999,999 cm. With r_inner and r_outer at most
#: this, every reading fits whatever kappa_eq, the moment or the poses.
MAX_READING_M = MAX_D_CM / 100.0

#: (lo, hi) of the model's lengths and strengths; r_en, kappa_eq, moment and q keep w_en
#: and cbrt(kappa_eq / (4 pi w_en)) within about 1e-60 .. 1e60 (noise on).
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

#: Control steps per epoch a closed loop may take (control_rate_hz / rate_hz; 1e308 Hz
#: used to loop for ever).
MAX_CONTROL_STEPS_PER_EPOCH = 1000

#: Coordinates of a vehicle's start, search area and terrain origin: +-1000 km.
MAX_VEHICLE_COORD_M = 1e6

#: receiver.vehicle numbers: (lo, hi); lo 0 means "> 0" for keys that must be positive.
#: Physical limits, so a position never leaves the float range (v_max = 1e308 did).
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

