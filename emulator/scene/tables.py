"""The scene file's tables as schema structs (:mod:`emulator.schema`): every key, its type,
length and range, written once. :mod:`emulator.scene.reader` converts a decoded TOML
document to :class:`SceneTable` and builds the scene from it; receiver profiles share the
model, display and rate rules. Units: metres, seconds, Hz; quaternions ``[w, x, y, z]``.
:class:`TableReader` words the errors, also for tables a scene's parts convert themselves
(:func:`emulator.closed_loop.vehicle.parse_vehicle`).

The ranges come first: a scene that validates must run (no reading the encoder refuses,
no division by zero, no overflow, no loop without end: issue 16). Each limit says which
of these it rules out; docs/emulator.md "Limits: what a scene may ask for" lists them for
users with the reasons.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import msgspec

from firmware_proto.errors import InputError, SceneError
from firmware_proto.sentences import MAX_CHANNELS, MAX_D_CM, MAX_ID

from emulator.files import MAX_TOML_BYTES, FileRefused, read_regular
from emulator.frames.trajectory import IDENTITY
from emulator.receiver.model import ANTENNAS
from emulator.schema import Finite, Int, Number, SchemaError, Strict, Text, Vector2, Vector3, Vector4, convert, join_key

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

#: Stream rates a scene may ask for, Hz: one epoch per 1000 s up to 10 kHz (epoch k is
#: at k / rate: a rate of 1e-320 Hz would put epoch 1 beyond any float).
RATE_LIMITS_HZ = (1e-3, 1e4)
Rate = Number(*RATE_LIMITS_HZ, unit="Hz")
Id = Int(0, MAX_ID)
Int32 = Int(-(2**31), 2**31)  # ranges checked by the effect's config class
Q = Number(MIN_Q, 1.0)
T = TypeVar("T")


class Waypoint(Strict):
    t: Finite
    position: Vector3
    orientation: Vector4 = IDENTITY


class Posed(Strict):
    """A device's pose: ``position`` (+ ``orientation``) or a ``path`` of waypoints."""

    position: Vector3 | None = None
    orientation: Vector4 | None = None
    path: Annotated[list[Waypoint], msgspec.Meta(min_length=1)] | None = None
    gps: bool = False  # emit an emulated GPS stream for this device
    attitude: bool = False  # emit an emulated $PASHR attitude stream


class TransmitterTable(Posed, kw_only=True):
    id: Id
    pulse_period_ms: Finite | None = None
    pulse_phase_ms: Finite | None = None


class ReceiverTable(Posed):
    id: Id | None = None
    channels: Int(1, MAX_CHANNELS) | None = None
    vehicle: dict | None = None  # emulator.closed_loop.vehicle reads it
    antennas: Int(min(ANTENNAS), max(ANTENNAS)) | None = None
    profile: str | None = None


def _model_table(name: str, keys) -> type:
    """A ``[model]`` table of ``keys`` (None: the profile's or the default value)."""
    fields = [(k, Number(*MODEL_LIMITS[k]) | None, None) for k in keys] + [("q", tuple[Q, Q, Q] | None, None)]
    return msgspec.defstruct(name, fields, bases=(Strict,), module=__name__)


ModelTable = _model_table("ModelTable", MODEL_LIMITS)
#: A receiver profile's ``[model]``: the transmitter's moment is not a receiver's.
ProfileModelTable = _model_table("ProfileModelTable", [k for k in MODEL_LIMITS if k != "moment"])


class EffectsTable(Strict):
    noise: bool = False
    research_sentences: bool = False
    pulses: bool = False
    quantize: bool | None = None  # None: not given (a receiver profile's display applies)
    ground_truth_error: bool = False
    link_faults: bool = False


class PulsesTable(Strict):
    period_ms: Vector2 | None = None
    pulse_ms: Finite | None = None
    drift_ppm: Finite | None = None
    overlap: str | None = None


class QuantizeTable(Strict):
    profile: str | None = None
    delta_step_deg: Int32 | None = None
    d_step_cm: Int32 | None = None
    d_far_cm: Int32 | None = None
    d_step_far_cm: Int32 | None = None


# The effects' own config classes check the low ends; these close the top (issue 16): a
# stall is a real pause at speed > 0 (1e308 ms hung); outages are scene time but a day is
# plenty; GPS errors beyond 10 km mean nothing (1.8e308 overflowed the noise draw).
GpsSigma = Number(0.0, 1e4, unit="")
GpsBias = Number(-1e4, 1e4, unit="")


class GroundTruthErrorTable(Strict):
    gps_sigma_m: tuple[GpsSigma, GpsSigma, GpsSigma] | None = None
    gps_bias_m: tuple[GpsBias, GpsBias, GpsBias] | None = None
    gps_dropout: Finite | None = None
    attitude_sigma_deg: Finite | None = None


class LinkFaultsTable(Strict):
    loss: Finite | None = None
    corrupt: Finite | None = None
    split: Finite | None = None
    stall: Finite | None = None
    stall_ms: Number(0.0, 60_000.0) | None = None
    disconnect_every_s: Number(0.0, 86_400.0) | None = None
    disconnect_s: Number(0.0, 86_400.0) | None = None
    streams: list[str] | None = None  # stream labels the faults apply to (none: all)


class OriginTable(Strict):
    lat: Finite
    lon: Finite
    alt: Finite = 0.0


class GroundTruthTable(Strict):
    start_utc: Any = None  # a TOML date-time or an ISO 8601 string (the reader checks it)
    gps_rate_hz: Rate = 1.0
    attitude_rate_hz: Rate = 10.0
    talker: Text("^[A-Z]{2}$", "two upper-case letters (GP, GN, ...)") = "GP"
    #: Decimals of arc-minutes in GGA/RMC (5 = 1.9 cm, 7 = 0.2 mm).
    lat_lon_decimals: Int(4, 7) = 5


class SceneTable(Strict):
    spec: Int(1, 2**31)
    seed: Int(0, 2**63 - 1) = 0
    rate_hz: Rate | None = None
    name: str = ""
    description: str = ""
    model: ModelTable = ModelTable()
    effects: EffectsTable = EffectsTable()
    transmitters: list[TransmitterTable] = []
    receiver: ReceiverTable | None = None
    receivers: Annotated[list[ReceiverTable], msgspec.Meta(min_length=1)] | None = None
    pulses: PulsesTable | None = None
    quantize: QuantizeTable | None = None
    ground_truth_error: GroundTruthErrorTable | None = None
    link_faults: LinkFaultsTable | None = None
    origin: OriginTable | None = None
    ground_truth: GroundTruthTable = GroundTruthTable()


class TableReader:
    """A scene file's errors as ``FILE: key.path: reason``: tables converted to their
    structs, configs built, the format version gated."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, reason: str) -> SceneError:
        return SceneError(self.source, key, reason)

    def convert(self, value: Any, type_: Any, path: str) -> Any:
        """``value`` as ``type_`` (:func:`emulator.schema.convert`), errors under ``path``."""
        try:
            return convert(value, type_)
        except SchemaError as exc:
            raise self.fail(join_key(path, exc.key), exc.reason) from None

    def build(self, key: str, factory: Callable[..., T], **kwargs: Any) -> T:
        """``factory(**kwargs)``, its :class:`InputError` (a check across keys) named by ``key``."""
        try:
            return factory(**kwargs)
        except InputError as exc:
            raise self.fail(key, str(exc)) from None

    def version(self, data: dict, key: str, newest: int) -> int:
        """The document's format version ``key``: present, an integer, at most ``newest``."""
        if key not in data:
            raise self.fail(key, f"missing (this program reads {key} = {newest})")
        version = self.convert(data[key], Int(1, 2**31), key)
        if version > newest:
            raise self.fail(key, f"version {version} is newer than this program supports ({newest})")
        return version


def toml_document(raw: bytes | str, source: str) -> dict:
    """A decoded TOML document (scene, profile); what is wrong with its text as one line."""
    try:
        return tomllib.loads(raw.decode("utf-8") if isinstance(raw, bytes) else raw)
    except UnicodeDecodeError as exc:
        raise SceneError(source, "", f"not UTF-8 text (byte offset {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"TOML syntax: {exc}") from None
    except RecursionError:  # tomllib recurses once per nesting level
        raise SceneError(source, "", "TOML nested too deeply") from None


def toml_file(path: str | Path, what: str) -> dict:
    """:func:`toml_document` of a regular file (``what``: "scene file", "profile file")."""
    try:
        return toml_document(read_regular(path, MAX_TOML_BYTES, what), str(path))
    except FileRefused as exc:
        raise SceneError(str(path), "", exc.reason) from None
