"""Emulated ground truth: a GPS (NMEA RMC + GGA) and an attitude unit ($PASHR) riding on
a receiver or a transmitter, each on its own port, from the device's scene trajectory.

Epoch k of a ground-truth stream is at scene time k / rate (s) and carries the UTC time
``ground_truth.start_utc + k / rate``. ENU positions (metres) are mapped to WGS-84
through the scene's ``[origin]``; velocity (m/s, for RMC speed and course) is that of
the path segment being travelled. With ``ground_truth_error`` a dropped fix is sent as
a no-fix RMC + GGA, as a receiver does. Details: docs/emulator.md "Ground-truth streams".
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass

import numpy as np

from emulator.truth.error import GroundTruthError
from emulator.frames.geodesy import enu_to_geodetic
from emulator.truth.nmea import gga_sentence, gps_sentences, pashr_from_quaternions, rmc_sentence
from emulator.scene.types import ReceiverSpec, Scene, Transmitter, truth_streams
from emulator.output.streams import Stream
from emulator.frames.trajectory import Trajectory


class _TruthStream(Stream):
    """A device's ground truth at the scene's ``ground_truth`` rate for this ``kind``
    (``gps_rate_hz`` / ``attitude_rate_hz``), with its ``ground_truth_error`` (or None)."""

    def __init__(self, scene: Scene, trajectory: Trajectory, label: str, error: GroundTruthError | None) -> None:
        super().__init__(label, getattr(scene.ground_truth, f"{self.kind}_rate_hz"))
        self.trajectory = trajectory
        self.origin = scene.origin
        self.spec = scene.ground_truth
        self.error = error


class GpsStream(_TruthStream):
    kind = "gps"

    def render(self, k0: int, count: int) -> bytes:
        t = (k0 + np.arange(count, dtype=np.float64)) / self.rate_hz
        pos, _ = self.trajectory.at(t)
        velocity = self.trajectory.velocity(t)
        valid = np.ones(count, dtype=bool)
        if self.error is not None:
            pos, valid = self.error.gps(pos)
        lat, lon, alt = enu_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2], self.origin)
        out = []
        talker = self.spec.talker
        for i in range(count):
            utc = self.spec.start_utc + _dt.timedelta(seconds=float(t[i]))
            if valid[i]:
                out.append(
                    gps_sentences(
                        utc, float(lat[i]), float(lon[i]), float(alt[i]), velocity_enu=velocity[i],
                        talker=talker, lat_lon_decimals=self.spec.lat_lon_decimals, short=True,
                    )
                )
            else:
                out.append(
                    rmc_sentence(utc, None, None, valid=False, talker=talker)  # no fix: empty position
                    + gga_sentence(utc, None, None, None, quality=0, sats=0, hdop=99.99, talker=talker)
                )
        return b"".join(out)


class AttitudeStream(_TruthStream):
    kind = "attitude"

    def render(self, k0: int, count: int) -> bytes:
        t = (k0 + np.arange(count, dtype=np.float64)) / self.rate_hz
        _, quat = self.trajectory.at(t)
        if self.error is not None:
            quat = self.error.attitude(quat)
        start = self.spec.start_utc
        return pashr_from_quaternions([start + _dt.timedelta(seconds=float(x)) for x in t], quat)


@dataclass(frozen=True)
class TruthCarrier:
    """One ground-truth stream of the scene: its label, kind (``gps`` / ``attitude``), the
    device that carries it and the spawn key of its ``ground_truth_error`` draws."""

    label: str
    kind: str
    device: ReceiverSpec | Transmitter
    error_stream: int


def ground_truth_carriers(scene: Scene) -> list[TruthCarrier]:
    """GPS and attitude streams of every device that asks for them, in
    :func:`~emulator.scene.types.truth_streams` order (labels from there too)."""
    # One error stream per ground-truth stream, after the receivers' noise streams.
    return [TruthCarrier(label, kind, dev, 1000 + i)
            for i, (label, kind, dev) in enumerate(truth_streams(scene.receivers, scene.transmitters))]


def ground_truth_stream(scene: Scene, carrier: TruthCarrier) -> Stream:
    """The stream of one carrier (see :func:`ground_truth_carriers`)."""
    fx = scene.effects.ground_truth_error
    error = GroundTruthError(fx, scene.seed, stream=carrier.error_stream) if fx is not None else None
    cls = GpsStream if carrier.kind == "gps" else AttitudeStream
    return cls(scene, carrier.device.trajectory, carrier.label, error)

