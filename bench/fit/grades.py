"""Pose-error sigmas by device grade (``arva-bench fit --gps-grade`` / ``--imu-grade``;
docs/calibration.md, "Identifiability"). A grade holds the sigma at its value instead of
estimating it, as ``--gps-sigma`` / ``--attitude-sigma`` do.

GPS: horizontal error per axis in m (the vertical is 1.5x), the grades of
docs/accuracy.md (b)'s emulated campaigns (RTK, SBAS, an uncorrected consumer
receiver). IMU: attitude error per body axis in degrees (a magnetometer-aided consumer
MEMS unit; a tactical-grade IMU). No numpy here: the command line imports it at load.
"""

from __future__ import annotations

GPS_GRADES = {"consumer": 1.5, "sbas": 0.5, "rtk": 0.02}
IMU_GRADES = {"consumer": 2.0, "tactical": 0.1}
#: Vertical / horizontal GPS error of a grade, and of --gps-sigma H without V.
GPS_GRADE_RATIO = 1.5
