"""Shared by the MAVLink pose tests (tests/emulator/closed_loop/test_mavlink_*.py): a free
UDP port on the loopback, and attitudes in the autopilot's convention (FRD body -> NED)."""

from __future__ import annotations

import socket

from scipy.spatial.transform import Rotation


def free_udp_port() -> int:
    """A UDP port of 127.0.0.1 nobody had bound a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ned_quaternion(yaw_deg, pitch_deg=0.0, roll_deg=0.0):
    """[w, x, y, z] of FRD -> NED for aerospace yaw (from north, clockwise), pitch, roll."""
    return Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_quat(scalar_first=True)
