"""The receiver's pose from an autopilot over MAVLink (pymavlink; extra ``mavlink``).

docs/closed_loop.md, "External loop", describes the protocol: the latest
``LOCAL_POSITION_NED`` (#32) and ``ATTITUDE_QUATERNION`` (#31) or ``ATTITUDE`` (#30;
ignored once a link has carried a quaternion) make the pose; we send a GCS
``HEARTBEAT`` every second and, on each autopilot ``HEARTBEAT``, ask with
``MAV_CMD_SET_MESSAGE_INTERVAL`` for the streams still missing; one warning after
``WARN_AFTER_S`` of positions without attitude (or the reverse). Frames: NED/FRD ->
ENU/FLU by :mod:`emulator.frames.mavlink`, the autopilot's local origin at ``origin`` in
the scene's ENU metres. Reads block at most 0.2 s at a time so :meth:`MavlinkPoseSource.close`
is prompt; :meth:`MavlinkPoseSource.wait` takes a timeout.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass

from firmware_proto.errors import MissingExtra

from emulator.frames.mavlink import attitude_euler_to_flu_enu, frd_ned_to_flu_enu, ned_to_enu

log = logging.getLogger("arva-emulate")

#: Message ids (MAVLink common) and the command that asks for a message stream.
MSG_LOCAL_POSITION_NED = 32
MSG_ATTITUDE_QUATERNION = 31
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
#: Seconds between our heartbeats.
HEARTBEAT_PERIOD_S = 1.0
#: Positions without attitude (or the reverse) this long earn one warning, by what came.
WARN_AFTER_S = 2.0
_HALF_POSE = {
    "position": "LOCAL_POSITION_NED arrives but no ATTITUDE_QUATERNION or ATTITUDE: epochs stay at the "
                "start pose (enable an attitude stream on the autopilot)",
    "attitude": "attitude arrives but no LOCAL_POSITION_NED: epochs stay at the start pose "
                "(does the autopilot have a position estimate?)",
}


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
    """Latest pose from LOCAL_POSITION_NED + ATTITUDE_QUATERNION (or ATTITUDE) on a
    pymavlink link (see the module docstring).

    ``start()`` opens the connection and a daemon reader thread; ``latest()`` is the
    newest :class:`Pose` (None until a position and an attitude arrived); ``close()``
    stops it. ``counts`` counts the pose messages taken (``ATTITUDE`` appears once one
    arrives); ``heartbeats`` the autopilot's heartbeats, ``requests`` the
    SET_MESSAGE_INTERVAL commands sent.
    """

    MESSAGES = ("LOCAL_POSITION_NED", "ATTITUDE_QUATERNION")
    #: Every message type the reader thread takes from the link.
    RECEIVED = ("LOCAL_POSITION_NED", "ATTITUDE_QUATERNION", "ATTITUDE", "HEARTBEAT")

    def __init__(
        self, url: str, origin=(0.0, 0.0, 0.0), baud: int = 57600, source_system: int = 255, rate_hz: float = 20.0
    ) -> None:
        self.url = url
        self.origin = tuple(float(v) for v in origin)
        self.baud = baud
        self.source_system = source_system
        self.rate_hz = rate_hz
        self.counts = {name: 0 for name in self.MESSAGES}
        self.heartbeats = 0
        self.requests = 0
        self.warned: str | None = None
        self._lock = threading.Lock()
        self._have = threading.Event()
        self._stop = threading.Event()
        self._pos = None
        self._quat = None
        self._quaternion_seen = False
        self._first: dict[str, float] = {}  # "position" / "attitude" -> monotonic time first seen
        self._conn = None
        self._thread: threading.Thread | None = None
        self._next_heartbeat = 0.0

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
                self._send_heartbeat(conn, time.monotonic())
                msg = conn.recv_match(type=list(self.RECEIVED), blocking=True, timeout=0.2)
            except Exception:  # noqa: BLE001 - a bad packet or a closed link must not kill us
                if self._stop.is_set():
                    return
                time.sleep(0.05)
                continue
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT":
                self._on_heartbeat(conn, msg)
            else:
                self.handle(msg, time.monotonic())

    def _send_heartbeat(self, conn, now: float) -> None:
        """Our HEARTBEAT (a GCS), once a second: autopilots stream to peers they hear."""
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + HEARTBEAT_PERIOD_S
            conn.mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def _on_heartbeat(self, conn, msg) -> None:
        """An autopilot's HEARTBEAT: ask it for the pose streams until they arrive."""
        if getattr(msg, "autopilot", MAV_AUTOPILOT_INVALID) == MAV_AUTOPILOT_INVALID:
            return  # another GCS, or ourselves echoed by a router
        self.heartbeats += 1
        with self._lock:
            missing = [mid for mid, have in ((MSG_LOCAL_POSITION_NED, self._pos), (MSG_ATTITUDE_QUATERNION, self._quat))
                       if have is None]  # fmt: skip
        interval_us = 1e6 / self.rate_hz
        for mid in missing:
            conn.mav.command_long_send(
                msg.get_srcSystem(), msg.get_srcComponent(), MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                float(mid), interval_us, 0.0, 0.0, 0.0, 0.0, 0.0,
            )  # fmt: skip
            self.requests += 1

    def handle(self, msg, now: float) -> None:
        """Take one decoded message (also usable without the thread, e.g. from a log)."""
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            e, n, u = ned_to_enu((msg.x, msg.y, msg.z))
            pos = (self.origin[0] + e, self.origin[1] + n, self.origin[2] + u)
            vel = ned_to_enu((msg.vx, msg.vy, msg.vz))
            if not all(math.isfinite(c) for c in (*pos, *vel)):
                return
            with self._lock:
                self._pos = (pos, vel, now, int(msg.time_boot_ms))
            self._first.setdefault("position", now)
        elif kind in ("ATTITUDE_QUATERNION", "ATTITUDE"):
            if kind == "ATTITUDE" and self._quaternion_seen:
                return  # the same instant as the quaternion, in Euler angles
            try:
                if kind == "ATTITUDE":
                    q = attitude_euler_to_flu_enu(msg.roll, msg.pitch, msg.yaw)
                else:
                    q = frd_ned_to_flu_enu((msg.q1, msg.q2, msg.q3, msg.q4))
                    self._quaternion_seen = True
            except ValueError:
                return
            with self._lock:
                self._quat = q
            self._first.setdefault("attitude", now)
        else:
            return
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if self._pos is not None and self._quat is not None:
            self._have.set()
        else:
            self._warn_if_half(now)

    def _warn_if_half(self, now: float) -> None:
        """One warning when only positions (or only attitudes) have come for a while."""
        if self.warned is not None or len(self._first) != 1:
            return
        (have, since), = self._first.items()
        if now - since < WARN_AFTER_S:
            return
        self.warned = f"{self.url}: {_HALF_POSE[have]}"
        log.warning("%s", self.warned)

    def latest(self) -> Pose | None:
        with self._lock:
            if self._pos is None or self._quat is None:
                return None
            pos, vel, t, boot = self._pos
            return Pose(pos, vel, self._quat, t, boot)

    def wait(self, timeout: float) -> Pose:
        """Block until a full pose is known; ``TimeoutError`` after ``timeout`` seconds."""
        if not self._have.wait(timeout):
            raise TimeoutError(
                f"{self.url}: no LOCAL_POSITION_NED + ATTITUDE_QUATERNION (or ATTITUDE) within {timeout:g} s"
            )
        return self.latest()

