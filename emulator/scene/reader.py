"""Scene files (BRIEF 5): versioned TOML describing transmitters, a receiver and effects.

Validation is strict, in the pyvisa-sim manner: every key is known, every value has its
type, length and range checked (:class:`~emulator.scene.tables.TableReader`), and the
first problem raises :class:`SceneError` whose text is ``FILE: key.path: reason`` (one
line, naming the exact key). The result is a :class:`~emulator.scene.types.Scene`; the
scene types are also importable from here.
"""

from __future__ import annotations

import datetime as _dt
import math
import tomllib
from dataclasses import replace

from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from firmware_proto.errors import InputError, SceneError
from firmware_proto.sentences import MAX_CHANNELS, MAX_D_CM, MAX_ID

from emulator.closed_loop.vehicle import VehicleSpec, parse_vehicle
from emulator.files import MAX_TOML_BYTES, FileRefused, read_regular
from emulator.frames.geodesy import Origin
from emulator.frames.trajectory import Trajectory
from emulator.output.link_faults import LinkFaultConfig
from emulator.receiver.model import ANTENNAS, ModelParams
from emulator.receiver.profile import ReceiverProfile, load_profile
from emulator.receiver.pulses import PulseConfig
from emulator.receiver.quantize import QuantizeConfig, QuantizeEffect
from emulator.scene.limits import EFFECT_PARAM_LIMITS, MAX_CONTROL_STEPS_PER_EPOCH, MIN_Q, MODEL_LIMITS, stream_labels
from emulator.scene.tables import TableReader, type_name
from emulator.scene.types import (
    SPEC_VERSION,
    Effects,
    GroundTruthSpec,
    ReceiverSpec,
    Scene,
    Transmitter,
)
from emulator.truth.error import GroundTruthErrorConfig

DEFAULT_SCENE = "default.toml"


_TOP_KEYS = {
    "spec", "seed", "rate_hz", "name", "description", "model", "effects", "transmitters", "receiver", "receivers",
    "pulses", "quantize", "ground_truth_error", "link_faults", "origin", "ground_truth",
}

_MODEL_KEYS = {"kappa_eq", "moment", "r_inner", "r_outer", "r_en", "q"}
_EFFECT_KEYS = {"noise", "research_sentences", "pulses", "quantize", "ground_truth_error", "link_faults"}
_TX_KEYS = {"id", "position", "orientation", "path", "pulse_period_ms", "pulse_phase_ms", "gps", "attitude"}

# Parameter tables of the effects: key -> kind ("number", "integer", "string",
# ("vector", n), "strings"). Ranges are checked by each effect's config class.
_EFFECT_PARAMS: dict[str, dict[str, object]] = {
    "pulses": {"period_ms": ("vector", 2), "pulse_ms": "number", "drift_ppm": "number", "overlap": "string"},
    "quantize": {
        "profile": "string",
        "delta_step_deg": "integer",
        "d_step_cm": "integer",
        "d_far_cm": "integer",
        "d_step_far_cm": "integer",
    },
    "ground_truth_error": {
        "gps_sigma_m": ("vector", 3),
        "gps_bias_m": ("vector", 3),
        "gps_dropout": "number",
        "attitude_sigma_deg": "number",
    },
    "link_faults": {
        "loss": "number",
        "corrupt": "number",
        "split": "number",
        "stall": "number",
        "stall_ms": "number",
        "disconnect_every_s": "number",
        "disconnect_s": "number",
        "streams": "strings",
    },
}
_EFFECT_CONFIGS = {
    "pulses": PulseConfig,
    "quantize": QuantizeConfig,
    "ground_truth_error": GroundTruthErrorConfig,
    "link_faults": LinkFaultConfig,
}
_RX_KEYS = {"id", "channels", "position", "orientation", "path", "gps", "attitude", "vehicle", "antennas", "profile"}


def parse_scene(data: dict, source: str) -> Scene:
    """Validate a decoded TOML document; ``source`` names it in error messages."""
    rd = TableReader(source)
    if "spec" not in data:
        raise rd.fail("spec", f"missing (this program reads spec = {SPEC_VERSION})")
    spec = rd.integer(data, "spec", "spec", None, 1, 2**31)
    if spec > SPEC_VERSION:
        raise rd.fail("spec", f"version {spec} is newer than this program supports ({SPEC_VERSION})")
    rd.known_keys(data, "", _TOP_KEYS)
    seed = rd.integer(data, "seed", "seed", 0, 0, 2**63 - 1)
    profiles = _profiles(rd, data)
    rate_hz = rd.rate(data, "rate_hz", "rate_hz", 1.0 if "rate_hz" in data else _profile_rate(rd, profiles))
    name = data.get("name", "")
    if not isinstance(name, str):
        raise rd.fail("name", f"expected a string, got {type_name(name)}")
    if not isinstance(data.get("description", ""), str):
        raise rd.fail("description", f"expected a string, got {type_name(data['description'])}")

    m = rd.table(data, "model", "model", _MODEL_KEYS)
    defaults = ModelParams()
    q = tuple(rd.vector(m["q"], "model.q", 3)) if "q" in m else defaults.q
    for i, qi in enumerate(q):
        if not 0 < qi <= 1:
            raise rd.fail(f"model.q[{i}]", f"must be in (0, 1], got {qi:g}")
        if qi < MIN_Q:
            raise rd.fail(f"model.q[{i}]", f"must be >= {MIN_Q:g}, got {qi:g}")
    values = {
        k: rd.number(m, k, f"model.{k}", getattr(defaults, k), positive=True, limits=MODEL_LIMITS[k])
        for k in sorted(_MODEL_KEYS - {"q"})
    }
    try:
        model = ModelParams(q=q, **values)
    except InputError as exc:
        raise rd.fail("model", str(exc)) from None

    e = rd.table(data, "effects", "effects", _EFFECT_KEYS)
    enabled = {k: rd.boolean(e, k, f"effects.{k}", False) for k in sorted(_EFFECT_KEYS)}

    raw_txs = data.get("transmitters", [])
    if not isinstance(raw_txs, list):
        raise rd.fail("transmitters", f"expected an array of tables ([[transmitters]]), got {type_name(raw_txs)}")
    transmitters = []
    pulse_periods: dict[int, float] = {}
    pulse_phases: dict[int, float] = {}
    seen: dict[int, int] = {}
    for i, tx in enumerate(raw_txs):
        path = f"transmitters[{i}]"
        if not isinstance(tx, dict):
            raise rd.fail(path, f"expected a table, got {type_name(tx)}")
        rd.known_keys(tx, path, _TX_KEYS)
        tx_id = rd.integer(tx, "id", f"{path}.id", None, 0, MAX_ID)
        if tx_id in seen:
            raise rd.fail(f"{path}.id", f"duplicate id {tx_id} (also transmitters[{seen[tx_id]}].id)")
        seen[tx_id] = i
        transmitters.append(
            Transmitter(
                tx_id,
                rd.trajectory(tx, path),
                rd.boolean(tx, "gps", f"{path}.gps", False),
                rd.boolean(tx, "attitude", f"{path}.attitude", False),
            )
        )
        for key, target in (("pulse_period_ms", pulse_periods), ("pulse_phase_ms", pulse_phases)):
            if key in tx:
                if not enabled["pulses"]:
                    raise rd.fail(f"{path}.{key}", "given but effects.pulses is not enabled")
                target[tx_id] = rd.number(tx, key, f"{path}.{key}", None)
    transmitters.sort(key=lambda tx: tx.id)
    effects = _effects(rd, data, enabled, pulse_periods, pulse_phases)

    receivers = _receivers(rd, data, rate_hz, profiles, m, "quantize" in e)
    for rx in receivers:
        quantize = effects.quantize if rx.display is None else rx.display
        if quantize is not None:
            _check_quantized_range(rd, rx.model or model, quantize)
    if effects.link_fault_streams:
        labels = stream_labels(
            len(receivers),
            [(rx.id, rx.gps, rx.attitude) for rx in receivers],
            [(tx.id, tx.gps, tx.attitude) for tx in transmitters],
        )
        for i, label in enumerate(effects.link_fault_streams):
            if label not in labels:
                raise rd.fail(f"link_faults.streams[{i}]", f"no stream {label!r} in this scene (streams: {', '.join(labels)})")
    origin, ground_truth = _ground_truth(rd, data, transmitters, receivers)
    if effects.ground_truth_error is not None and not any(d.gps or d.attitude for d in (*transmitters, *receivers)):
        raise rd.fail("effects.ground_truth_error", "no device has gps or attitude streams to apply it to")
    return Scene(
        source, spec, seed, rate_hz, receivers[0].model or model, effects, tuple(transmitters), receivers, name,
        origin, ground_truth,
    )


def _check_quantized_range(rd: TableReader, model: ModelParams, cfg: QuantizeConfig) -> None:
    """The largest reading (r_inner or r_outer, in cm) must still encode once rounded to
    the display steps: rounding is monotone, so checking the largest is enough."""
    largest = int(round(max(model.r_inner, model.r_outer) * 100.0))
    d, _ = QuantizeEffect(cfg).apply(np.array([largest]), np.array([0]), np.array([False]))
    if int(d[0]) > MAX_D_CM:
        key = "quantize.d_step_far_cm" if cfg.d_far_cm is not None and largest >= cfg.d_far_cm else "quantize.d_step_cm"
        raise rd.fail(key, f"the largest reading ({largest} cm, from model.r_inner / r_outer) would round to {int(d[0])} cm, "
                           f"beyond the protocol's {MAX_D_CM}")


def _check_model_limits(rd: TableReader, model: ModelParams) -> None:
    """A receiver's final model (defaults, profile, scene keys) within emulator.scene.limits."""
    for key, (lo, hi) in MODEL_LIMITS.items():
        value = getattr(model, key)
        if not lo <= value <= hi:
            raise rd.fail(f"model.{key}", f"must be within [{lo:.10g}, {hi:.10g}], got {value:g}")
    for i, qi in enumerate(model.q):
        if qi < MIN_Q:
            raise rd.fail(f"model.q[{i}]", f"must be >= {MIN_Q:g}, got {qi:g}")


def _ground_truth(rd: TableReader, data: dict, transmitters, receivers) -> tuple[Origin | None, GroundTruthSpec]:
    """``[origin]`` (geodetic, for GPS) and ``[ground_truth]`` (stream settings)."""
    o = rd.table(data, "origin", "origin", {"lat", "lon", "alt"})
    origin = None
    if o:
        values = {k: rd.number(o, k, f"origin.{k}", 0.0 if k == "alt" else None) for k in ("lat", "lon", "alt")}
        try:
            origin = Origin(**values)
        except InputError as exc:
            raise SceneError(rd.source, "", str(exc)) from None
    g = rd.table(
        data, "ground_truth", "ground_truth", {"start_utc", "gps_rate_hz", "attitude_rate_hz", "talker", "lat_lon_decimals"}
    )
    defaults = GroundTruthSpec()
    start = g.get("start_utc", defaults.start_utc)
    if isinstance(start, str):
        try:
            start = _dt.datetime.fromisoformat(start.replace("Z", "+00:00"))
        except ValueError:
            raise rd.fail("ground_truth.start_utc", f"not an ISO 8601 date-time: {start!r}") from None
    if not isinstance(start, _dt.datetime):
        raise rd.fail("ground_truth.start_utc", f"expected a date-time, got {type_name(start)}")
    if start.tzinfo is None:
        raise rd.fail("ground_truth.start_utc", "needs a time zone (e.g. 2026-01-15T10:00:00Z)")
    talker = g.get("talker", defaults.talker)
    if not (isinstance(talker, str) and len(talker) == 2 and talker.isalpha() and talker.isupper()):
        raise rd.fail("ground_truth.talker", f"expected two upper-case letters (GP, GN, ...), got {talker!r}")
    spec = GroundTruthSpec(
        start.astimezone(_dt.timezone.utc),
        rd.rate(g, "gps_rate_hz", "ground_truth.gps_rate_hz", defaults.gps_rate_hz),
        rd.rate(g, "attitude_rate_hz", "ground_truth.attitude_rate_hz", defaults.attitude_rate_hz),
        talker,
        rd.integer(g, "lat_lon_decimals", "ground_truth.lat_lon_decimals", defaults.lat_lon_decimals, 4, 7),
    )
    if origin is None:
        for rx in receivers:
            if rx.gps:
                raise rd.fail("origin", f"missing table: receiver {rx.id} has gps = true, which needs a geodetic origin")
        for tx in transmitters:
            if tx.gps:
                raise rd.fail("origin", f"missing table: transmitter {tx.id} has gps = true, which needs a geodetic origin")
    return origin, spec


def _effects(rd: TableReader, data: dict, enabled: dict[str, bool], periods: dict, phases: dict) -> Effects:
    """Each enabled effect's config from its own table (``[pulses]``, ``[quantize]`` ...).

    A parameter table for an effect that is not enabled is an error: a scene that sets
    ``[pulses]`` and forgets ``effects.pulses = true`` would otherwise silently differ.
    """
    configs: dict[str, object] = {}
    streams: tuple[str, ...] = ()
    for name, schema in _EFFECT_PARAMS.items():
        table = rd.table(data, name, name, set(schema))
        if table and not enabled[name]:
            raise rd.fail(name, f"parameters given but effects.{name} is not enabled")
        if not enabled[name]:
            continue
        kwargs = {key: _param(rd, table, key, f"{name}.{key}", kind) for key, kind in schema.items() if key in table}
        if name == "link_faults":
            streams = tuple(kwargs.pop("streams", ()))
        if name == "pulses":
            kwargs.update(periods_ms=periods, phases_ms=phases)
        try:
            configs[name] = _EFFECT_CONFIGS[name](**kwargs)
        except InputError as exc:
            raise SceneError(rd.source, "", str(exc)) from None
    return Effects(
        noise=enabled["noise"],
        research_sentences=enabled["research_sentences"],
        link_fault_streams=streams,
        **configs,
    )


def _param(rd: TableReader, table: dict, key: str, path: str, kind: object):
    limits = EFFECT_PARAM_LIMITS.get(path)
    if kind == "number":
        return rd.number(table, key, path, None, limits=limits)
    if kind == "integer":
        return rd.integer(table, key, path, None, -(2**31), 2**31)
    if kind == "string":
        value = table[key]
        if not isinstance(value, str):
            raise rd.fail(path, f"expected a string, got {type_name(value)}")
        return value
    if kind == "strings":
        value = table[key]
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise rd.fail(path, "expected an array of strings")
        return value
    values = rd.vector(table[key], path, kind[1])
    if limits is not None:
        for i, v in enumerate(values):
            if not limits[0] <= v <= limits[1]:
                raise rd.fail(f"{path}[{i}]", f"must be within [{limits[0]:.10g}, {limits[1]:.10g}], got {v:g}")
    return tuple(values)


def _receiver_tables(data: dict) -> list[tuple[Any, str]]:
    """The raw receiver tables with their key paths (unchecked; :func:`_receivers` checks)."""
    if "receivers" in data and isinstance(data["receivers"], list):
        return [(r, f"receivers[{i}]") for i, r in enumerate(data["receivers"])]
    return [(data.get("receiver"), "receiver")]


def _profiles(rd: TableReader, data: dict) -> list[ReceiverProfile | None]:
    """Each receiver's profile (``profile = "NAME"``), None where it names none."""
    out: list[ReceiverProfile | None] = []
    for table, path in _receiver_tables(data):
        name = table.get("profile") if isinstance(table, dict) else None
        if name is None:
            out.append(None)
            continue
        if not isinstance(name, str):
            raise rd.fail(f"{path}.profile", f"expected a string, got {type_name(name)}")
        try:
            out.append(load_profile(name))
        except InputError as exc:
            raise rd.fail(f"{path}.profile", str(exc)) from None
    return out


def _profile_rate(rd: TableReader, profiles: list[ReceiverProfile | None]) -> float:
    """The epoch rate the profiles ask for when the scene gives no ``rate_hz`` (one rate
    per scene: profiles that disagree need the scene to choose)."""
    rates = {p.rate_hz: p.name for p in profiles if p is not None}
    if len(rates) > 1:
        names = ", ".join(f"{n} {r:g} Hz" for r, n in rates.items())
        raise rd.fail("rate_hz", f"missing: the receivers' profiles differ in epoch rate ({names}); set rate_hz")
    return next(iter(rates), 1.0)


def _receiver_model(rd: TableReader, profile: ReceiverProfile | None, m: dict, r: dict, path: str) -> ModelParams:
    """Defaults, then the profile, then the scene's ``[model]`` keys, then ``antennas``."""
    base = profile.model if profile is not None else ModelParams()
    values = {
        k: rd.number(m, k, f"model.{k}", None, positive=True, limits=MODEL_LIMITS[k])
        for k in sorted(_MODEL_KEYS - {"q"})
        if k in m
    }
    if "q" in m:
        values["q"] = tuple(rd.vector(m["q"], "model.q", 3))
    values["antennas"] = rd.integer(r, "antennas", f"{path}.antennas", base.antennas, min(ANTENNAS), max(ANTENNAS))
    try:
        model = replace(base, **values)
    except InputError as exc:
        raise rd.fail("model", str(exc)) from None
    _check_model_limits(rd, model)
    return model


def _receivers(
    rd: TableReader,
    data: dict,
    rate_hz: float = 1.0,
    profiles: list[ReceiverProfile | None] | None = None,
    model_keys: dict | None = None,
    scene_sets_quantize: bool = False,
) -> tuple[ReceiverSpec, ...]:
    """``[receiver]`` (one) or ``[[receivers]]`` (several, each on its own port).

    A receiver's ``profile`` gives its class, channels, model constants and display;
    the scene's own keys (``channels``, ``antennas``, ``[model]``, ``effects.quantize``)
    override it."""
    if "receiver" in data and "receivers" in data:
        raise rd.fail("receivers", "give either [receiver] or [[receivers]], not both")
    if "receivers" not in data:
        tables = [(rd.table(data, "receiver", "receiver", _RX_KEYS, required=True), "receiver")]
    else:
        raw = data["receivers"]
        if not isinstance(raw, list) or not raw:
            raise rd.fail("receivers", "expected a non-empty array of tables ([[receivers]])")
        tables = []
        for i, r in enumerate(raw):
            if not isinstance(r, dict):
                raise rd.fail(f"receivers[{i}]", f"expected a table, got {type_name(r)}")
            rd.known_keys(r, f"receivers[{i}]", _RX_KEYS)
            tables.append((r, f"receivers[{i}]"))
    out: list[ReceiverSpec] = []
    seen: dict[int, str] = {}
    for i, (r, path) in enumerate(tables):
        rx_id = rd.integer(r, "id", f"{path}.id", i + 1, 0, MAX_ID)
        if rx_id in seen:
            raise rd.fail(f"{path}.id", f"duplicate id {rx_id} (also {seen[rx_id]}.id)")
        seen[rx_id] = path
        profile = profiles[i] if profiles else None
        channels = rd.integer(r, "channels", f"{path}.channels", profile.channels if profile else 1, 1, MAX_CHANNELS)
        model = _receiver_model(rd, profile, model_keys or {}, r, path)
        display = profile.display if profile is not None and not scene_sets_quantize else None
        vehicle = _vehicle(rd, r, path, rate_hz) if "vehicle" in r else None
        out.append(
            ReceiverSpec(
                rx_id,
                channels,
                rd.trajectory(r, path) if vehicle is None else _start_pose(vehicle),
                rd.boolean(r, "gps", f"{path}.gps", False),
                rd.boolean(r, "attitude", f"{path}.attitude", False),
                vehicle,
                model,
                display,
                profile.name if profile is not None else "",
            )
        )
    return tuple(out)


def _vehicle(rd: TableReader, r: dict, path: str, rate_hz: float) -> VehicleSpec:
    """``[receiver.vehicle]``: the receiver rides on a vehicle (emulator.closed_loop.vehicle)."""
    for key in ("position", "orientation", "path", "gps", "attitude"):
        if key in r:
            why = "its pose comes from the vehicle" if key in ("position", "orientation", "path") else (
                "ground-truth streams are not emulated for a vehicle yet"
            )
            raise rd.fail(f"{path}.{key}", f"not allowed with {path}.vehicle: {why}")
    source = Path(rd.source)
    vehicle = parse_vehicle(rd, r["vehicle"], f"{path}.vehicle", source.parent if source.is_file() else None)
    ratio = vehicle.control_rate_hz / rate_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise rd.fail(
            f"{path}.vehicle.control_rate_hz",
            f"must be a whole multiple of rate_hz = {rate_hz:g}, got {vehicle.control_rate_hz:g}",
        )
    if round(ratio) > MAX_CONTROL_STEPS_PER_EPOCH:
        raise rd.fail(
            f"{path}.vehicle.control_rate_hz",
            f"at most {MAX_CONTROL_STEPS_PER_EPOCH} control steps per epoch (rate_hz = {rate_hz:g}), "
            f"got {vehicle.control_rate_hz:g} Hz",
        )
    return vehicle


def _start_pose(vehicle: VehicleSpec) -> Trajectory:
    x, y = vehicle.start
    z = vehicle.terrain.height(x, y) + vehicle.height_start
    yaw = math.radians(vehicle.yaw_deg)
    return Trajectory.static([x, y, z], [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file. Every failure is a one-line :class:`SceneError`."""
    source = str(path)
    try:
        raw = read_regular(path, MAX_TOML_BYTES, "scene file")
    except FileRefused as exc:
        raise SceneError(source, "", exc.reason) from None
    return loads_scene(raw, source)


def loads_scene(raw: bytes | str, source: str) -> Scene:
    try:
        text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
    except UnicodeDecodeError as exc:
        raise SceneError(source, "", f"not UTF-8 text (byte offset {exc.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"TOML syntax: {exc}") from None
    except RecursionError:  # tomllib recurses once per nesting level
        raise SceneError(source, "", "TOML nested too deeply") from None
    return parse_scene(data, source)


def default_scene() -> Scene:
    """The embedded default: the paper's four case-study transmitters, 4 channels."""
    ref = resources.files("emulator") / "scenes" / DEFAULT_SCENE
    return loads_scene(ref.read_bytes(), f"<embedded {DEFAULT_SCENE}>")
