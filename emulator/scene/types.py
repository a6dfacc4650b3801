"""The types of a validated scene (BRIEF 5): transmitters, receivers, effects, ground truth.

Built only by :mod:`emulator.scene.reader` (which checks every value); read by every
stage of the pipeline. Positions are world ENU metres, orientations unit quaternions
[w, x, y, z] body to world (BRIEF 2), times scene seconds, rates Hz.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from emulator.closed_loop.vehicle import VehicleSpec
from emulator.frames.geodesy import Origin
from emulator.frames.trajectory import Trajectory
from emulator.output.link_faults import LinkFaultConfig
from emulator.receiver.model import ModelParams
from emulator.receiver.pulses import PulseConfig
from emulator.receiver.quantize import QuantizeConfig
from emulator.truth.error import GroundTruthErrorConfig

#: The newest scene format this program reads.
SPEC_VERSION = 1


@dataclass(frozen=True)
class Effects:
    """Which effects the scene enables; all off by default (BRIEF 3.1).

    An effect with parameters is ``None`` when off, else its validated config.
    """

    noise: bool = False
    research_sentences: bool = False
    pulses: PulseConfig | None = None
    quantize: QuantizeConfig | None = None
    ground_truth_error: GroundTruthErrorConfig | None = None
    link_faults: LinkFaultConfig | None = None
    #: Stream labels the link faults apply to (empty: every stream).
    link_fault_streams: tuple[str, ...] = ()


@dataclass(frozen=True)
class Transmitter:
    id: int
    trajectory: Trajectory
    gps: bool = False  # emit an emulated GPS stream for this device
    attitude: bool = False  # emit an emulated $PASHR attitude stream


@dataclass(frozen=True)
class GroundTruthSpec:
    """Emulated ground-truth streams: rates, the UTC of scene time 0, NMEA talker."""

    start_utc: _dt.datetime = _dt.datetime(2026, 1, 1, tzinfo=_dt.timezone.utc)
    gps_rate_hz: float = 1.0
    attitude_rate_hz: float = 10.0
    talker: str = "GP"
    #: Decimals of arc-minutes in GGA/RMC, 4..7: 5 = 1.9 cm, 7 = 0.2 mm (u-blox "high
    #: precision" NMEA). Every value keeps the emulated sentences within NMEA's 82 bytes.
    lat_lon_decimals: int = 5


@dataclass(frozen=True)
class ReceiverSpec:
    """One receiver: ``id`` names its streams (``arva:<id>`` when there are several)."""

    id: int
    channels: int
    trajectory: Trajectory
    gps: bool = False
    attitude: bool = False
    #: Closed loop: the vehicle that carries this receiver (its pose then comes from the
    #: vehicle, ``trajectory`` is only the start pose). None: the scene's trajectory.
    vehicle: VehicleSpec | None = None
    #: This receiver's model: its class (antennas) and constants, from its profile with
    #: the scene's keys over it. None: the scene's ``model``.
    model: ModelParams | None = None
    #: Display quantisation from the profile, used when the scene says nothing about
    #: ``effects.quantize`` (None: the scene's ``effects.quantize``).
    display: QuantizeConfig | None = None
    #: Name of the receiver profile (emulator/receiver/profiles), "" for none.
    profile: str = ""


@dataclass(frozen=True)
class Scene:
    """A validated scene. Transmitters are sorted by ascending id."""

    source: str
    spec: int
    seed: int
    rate_hz: float
    #: The first receiver's model (its class, profile and the scene's [model]); see
    #: :meth:`receiver_model` for the others.
    model: ModelParams
    effects: Effects
    transmitters: tuple[Transmitter, ...]
    receivers: tuple[ReceiverSpec, ...]
    name: str = ""
    origin: Origin | None = None
    ground_truth: GroundTruthSpec = GroundTruthSpec()

    @property
    def receiver(self) -> ReceiverSpec:
        """The first (usually the only) receiver."""
        return self.receivers[0]

    def receiver_model(self, index: int = 0) -> ModelParams:
        """The model receiver ``index`` measures with (its class and constants)."""
        return self.receivers[index].model or self.model

    @property
    def transmitter_ids(self) -> np.ndarray:
        return np.array([tx.id for tx in self.transmitters], dtype=np.int64)


def arva_labels(receivers: Sequence[ReceiverSpec]) -> list[str]:
    """Each receiver's ``$PARVA`` stream label: ``arva``, or ``arva:<id>`` with several."""
    return [f"arva:{rx.id}" if len(receivers) > 1 else "arva" for rx in receivers]


def truth_streams(
    receivers: Sequence[ReceiverSpec], transmitters: Sequence[Transmitter]
) -> list[tuple[str, str, ReceiverSpec | Transmitter]]:
    """(label, kind, device) of every GPS, then every attitude stream (BRIEF 6), receivers
    first: ``gps`` / ``attitude`` when one device streams that kind, else suffixed with
    the device, ``gps:rx`` (``gps:rx<id>`` with several receivers), ``gps:tx<id>``."""
    several_rx = len(receivers) > 1
    devices: list[tuple[str, ReceiverSpec | Transmitter]] = [
        (f"rx{rx.id}" if several_rx else "rx", rx) for rx in receivers
    ]
    devices += [(f"tx{tx.id}", tx) for tx in transmitters]
    out = []
    for kind in ("gps", "attitude"):
        carriers = [(name, dev) for name, dev in devices if getattr(dev, kind)]
        out += [(kind if len(carriers) == 1 else f"{kind}:{name}", kind, dev) for name, dev in carriers]
    return out
