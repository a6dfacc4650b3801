"""Streaming attitude reader for drones: MAVLink ``ATTITUDE_QUATERNION`` -> :class:`Attitude`.

A flight controller's telemetry port (or a MAVLink router's TCP output, e.g. an
ArduPilot SITL on ``socket://127.0.0.1:5760``) carries a binary MAVLink 1/2 stream.
This reader feeds those bytes to pymavlink's own parser (the ``mavlink`` extra, dialect
``ardupilotmega``, a superset of ``common``) and turns attitude messages into the same
:class:`~bench.ground_truth.attitude.Attitude` records as ``$PASHR``:

* ``ATTITUDE_QUATERNION`` (#31): q1..q4 = [w, x, y, z] rotating the FRD body frame into
  NED; converted to our FLU -> ENU quaternion (:func:`emulator.frames.mavlink.frd_ned_to_flu_enu`).
  ``repr_offset_q`` is a display hint for tail-sitters and is not applied.
* ``ATTITUDE`` (#30): roll, pitch, yaw in radians, the same aerospace Z-Y-X convention as
  ``$PASHR`` (yaw = heading clockwise from north). ArduPilot streams it by default, PX4
  streams the quaternion; once a stream has carried an ``ATTITUDE_QUATERNION``, later
  ``ATTITUDE`` messages (the same instant, in Euler angles) are ``ignored`` so each
  instant is recorded once.

Records carry ``time_boot_ms`` (the autopilot's clock) and no UTC: the session's own
monotonic/UTC read stamps date them. ``stats`` (a Counter) uses the NMEA readers' names
where the meaning is the same: ``bytes``, ``junk_bytes`` (bytes that were no MAVLink
frame), ``bad_checksum`` (a frame whose CRC failed), ``malformed`` (a degenerate
quaternion or a non-finite angle), ``ignored`` (other messages, or unknown ids),
``messages`` (frames decoded), ``attitudes`` (records emitted). Never raises on data;
pymavlink keeps at most one frame (<= 280 bytes) pending.
"""

from __future__ import annotations

from collections import Counter

from emulator.frames.attitude import hpr_to_quaternion, quaternion_to_hpr
from emulator.frames.mavlink import attitude_euler_to_hpr, frd_ned_to_flu_enu
from firmware_proto.errors import MissingExtra

from .attitude import Attitude


class MavlinkAttitudeReader:
    """``feed(bytes) -> list[Attitude]`` from a MAVLink byte stream; never raises on data."""

    def __init__(self, stats: Counter[str] | None = None) -> None:
        try:  # the mavlink extra
            from pymavlink.dialects.v20 import ardupilotmega as dialect
        except ImportError:
            raise MissingExtra("MAVLink attitude", "pymavlink", "mavlink") from None
        self._bad_data = dialect.MAVLink_bad_data
        self._parser = dialect.MAVLink(None)
        self._parser.robust_parsing = True  # bad bytes come back as MAVLink_bad_data, not raised
        self.stats: Counter[str] = Counter() if stats is None else stats
        self._quaternion_seen = False

    def feed(self, data: bytes) -> list[Attitude]:
        """Records completed by ``data``, in stream order."""
        self.stats["bytes"] += len(data)
        try:
            messages = self._parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - a third-party parser fed hostile bytes
            self.stats["malformed"] += 1
            self._drop_pending()  # resynchronise on the next frame
            return []
        return [att for att in map(self._handle, messages) if att is not None]

    def flush(self) -> list[Attitude]:
        """At end of input: a frame still pending is incomplete; it is counted, not read."""
        pending = self.pending
        if pending:
            self.stats["fragments"] += 1
            self.stats["junk_bytes"] += pending
            self._drop_pending()
        return []

    def _drop_pending(self) -> None:
        """Forget a partial frame (pymavlink keeps it in ``buf`` from ``buf_index``)."""
        self._parser.buf = bytearray()
        self._parser.buf_index = 0

    @property
    def pending(self) -> int:
        """Bytes of a frame still waiting for its end."""
        return self._parser.buf_len()

    def _handle(self, msg) -> Attitude | None:
        st = self.stats
        if isinstance(msg, self._bad_data):
            if "CRC" in msg.reason or "crc" in msg.reason:
                st["bad_checksum"] += 1
            else:
                st["junk_bytes"] += len(msg.data)
            return None
        st["messages"] += 1
        kind = msg.get_type()
        try:
            if kind == "ATTITUDE_QUATERNION":
                q = frd_ned_to_flu_enu((msg.q1, msg.q2, msg.q3, msg.q4))
                self._quaternion_seen = True
                heading, roll, pitch = (float(a) for a in quaternion_to_hpr(q))
            elif kind == "ATTITUDE" and not self._quaternion_seen:
                heading, roll, pitch = attitude_euler_to_hpr(msg.roll, msg.pitch, msg.yaw)
                q = tuple(float(c) for c in hpr_to_quaternion(heading, roll, pitch))
            else:
                st["ignored"] += 1
                return None
        except (ValueError, ArithmeticError):  # PoseError is a ValueError
            st["malformed"] += 1
            return None
        st["attitudes"] += 1
        q = tuple(float(c) + 0.0 for c in q)  # + 0.0: no -0.0 in the logs
        return Attitude(None, None, heading, roll, pitch, q, time_boot_ms=int(msg.time_boot_ms))
