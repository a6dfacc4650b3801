"""The receiver's pose from an autopilot over MAVLink (pymavlink; extra ``mavlink``).

The emulator "rides along" a SITL or a real flight: it listens for the autopilot's
``LOCAL_POSITION_NED`` (#32) and ``ATTITUDE_QUATERNION`` (#31) messages and keeps the
latest pose; the closed-loop receiver evaluates each epoch at that pose.

Frames (MAVLink common message set):

* ``LOCAL_POSITION_NED``: x north, y east, z down (metres) in the autopilot's local
  frame, velocities likewise. ENU (BRIEF 2) is (east, north, up) = (y, x, -z), i.e.
  p_enu = T p_ned with T = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]. The local origin (EKF
  origin / home) sits at ``origin`` in the scene's ENU frame.
* ``ATTITUDE_QUATERNION``: q1..q4 = [w, x, y, z] rotating the FRD body frame (x forward,
  y right, z down) into NED. Our body frame is FLU (x forward, y left, z up,
  BRIEF 2): v_frd = F v_flu with F = diag(1, -1, -1). So the receiver's rotation is
  R_enu_flu = T R_ned_frd F. T is the rotation by pi about (1, 1, 0)/sqrt(2), quaternion
  q_T = [0, 1/sqrt2, 1/sqrt2, 0]; F is the rotation by pi about x, q_F = [0, 1, 0, 0]; so
  q_enu_flu = q_T * q_ned_frd * q_F (Hamilton products). Heading: a NED yaw psi
  (clockwise from north) is the ENU yaw 90 deg - psi (counter-clockwise from east).

Use a pymavlink connection string: ``udpin:0.0.0.0:14550`` (listen for a SITL's or a
GCS-forwarded stream), ``udpout:HOST:PORT``, ``tcp:HOST:PORT``, or a serial device
``/dev/ttyUSB0`` (telemetry radio; ``baud`` applies). Reads block at most 0.2 s at a time
so :meth:`MavlinkPoseSource.close` is prompt; :meth:`wait` takes a timeout.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from firmware_proto.errors import MissingExtra

from emulator.frames.mavlink import attitude_euler_to_flu_enu, frd_ned_to_flu_enu, ned_to_enu

__all__ = ["MavlinkPoseSource", "Pose", "attitude_euler_to_flu_enu", "frd_ned_to_flu_enu", "ned_to_enu", "pose_arrays"]

@dataclass(frozen=True)
class Pose:
    """A receiver pose in the scene's ENU frame, from the latest messages."""

    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # [w, x, y, z], FLU body -> ENU
    t_position: float  # time.monotonic() when the position arrived
    time_boot_ms: int

    def extrapolated(self, t: float, horizon: float = 1.0) -> tuple[float, float, float]:
        """Position at monotonic time ``t``, by the reported velocity, at most ``horizon``
        seconds ahead of the message (a stale stream is held, not flown off)."""
        dt = min(max(t - self.t_position, 0.0), horizon)
        return tuple(p + v * dt for p, v in zip(self.position, self.velocity))


class MavlinkPoseSource:
    """Latest pose from LOCAL_POSITION_NED + ATTITUDE_QUATERNION on a pymavlink link.

    ``start()`` opens the connection and a daemon reader thread; ``latest()`` is the
    newest :class:`Pose` (None until both messages arrived); ``close()`` stops it.
    """

    MESSAGES = ("LOCAL_POSITION_NED", "ATTITUDE_QUATERNION")

    def __init__(self, url: str, origin=(0.0, 0.0, 0.0), baud: int = 57600, source_system: int = 255) -> None:
        self.url = url
        self.origin = tuple(float(v) for v in origin)
        self.baud = baud
        self.source_system = source_system
        self.counts = {name: 0 for name in self.MESSAGES}
        self.errors = 0
        self._lock = threading.Lock()
        self._have = threading.Event()
        self._stop = threading.Event()
        self._pos = None
        self._quat = None
        self._conn = None
        self._thread: threading.Thread | None = None

    @property
    def started(self) -> bool:
        return self._thread is not None

    def start(self) -> "MavlinkPoseSource":
        if self._thread is not None:
            return self
        try:
            from pymavlink import mavutil  # the optional extra: imported only when used
        except ImportError:
            raise MissingExtra("MAVLink pose input", "pymavlink", "mavlink") from None

        self._conn = mavutil.mavlink_connection(self.url, baud=self.baud, source_system=self.source_system)
        self._thread = threading.Thread(target=self._run, name=f"mavlink {self.url}", daemon=True)
        self._thread.start()
        return self

    def __enter__(self) -> "MavlinkPoseSource":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _run(self) -> None:
        conn = self._conn
        while not self._stop.is_set():
            try:
                msg = conn.recv_match(type=list(self.MESSAGES), blocking=True, timeout=0.2)
            except Exception:  # noqa: BLE001 - a bad packet or a closed link must not kill us
                if self._stop.is_set():
                    return
                self.errors += 1
                time.sleep(0.05)
                continue
            if msg is not None:
                self.handle(msg, time.monotonic())

    def handle(self, msg, now: float) -> None:
        """Take one decoded message (also usable without the thread, e.g. from a log)."""
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            e, n, u = ned_to_enu((msg.x, msg.y, msg.z))
            pos = (self.origin[0] + e, self.origin[1] + n, self.origin[2] + u)
            vel = ned_to_enu((msg.vx, msg.vy, msg.vz))
            if not all(math.isfinite(c) for c in (*pos, *vel)):
                self.errors += 1
                return
            with self._lock:
                self._pos = (pos, vel, now, int(msg.time_boot_ms))
        elif kind == "ATTITUDE_QUATERNION":
            try:
                q = frd_ned_to_flu_enu((msg.q1, msg.q2, msg.q3, msg.q4))
            except ValueError:
                self.errors += 1
                return
            with self._lock:
                self._quat = q
        else:
            return
        self.counts[kind] += 1
        if self._pos is not None and self._quat is not None:
            self._have.set()

    def latest(self) -> Pose | None:
        with self._lock:
            if self._pos is None or self._quat is None:
                return None
            pos, vel, t, boot = self._pos
            return Pose(pos, vel, self._quat, t, boot)

    def wait(self, timeout: float) -> Pose:
        """Block until a full pose is known; ``TimeoutError`` after ``timeout`` seconds."""
        if not self._have.wait(timeout):
            raise TimeoutError(f"{self.url}: no LOCAL_POSITION_NED + ATTITUDE_QUATERNION within {timeout:g} s")
        return self.latest()


def pose_arrays(pose: Pose, t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(1, 3) position and (1, 4) orientation arrays for the receiver model."""
    p = pose.position if t is None else pose.extrapolated(t)
    return np.array([p], dtype=np.float64), np.array([pose.orientation], dtype=np.float64)
