"""Scene files (BRIEF 5): versioned TOML describing transmitters, a receiver and effects.

The document is converted to the schema structs of :mod:`emulator.scene.tables` (every
key, type and range), then the rules across keys are checked here (ids unique, waypoint
times increasing, quaternions normalisable, effects enabled for their tables...). The
first problem is a one-line :class:`SceneError`, ``FILE: key.path: reason``; the result
a :class:`~emulator.scene.types.Scene`.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import replace
from functools import partial
from importlib import resources
from pathlib import Path

import numpy as np

from firmware_proto.errors import InputError, PoseError
from firmware_proto.sentences import MAX_D_CM

from emulator.closed_loop.vehicle import UAV, VehicleSpec, parse_vehicle
from emulator.frames.geodesy import Origin
from emulator.frames.rotation import normalize_quaternions
from emulator.frames.trajectory import IDENTITY, Trajectory
from emulator.output.link_faults import LinkFaultConfig
from emulator.receiver.model import ModelParams
from emulator.receiver.profile import ReceiverProfile, load_profile
from emulator.receiver.pulses import PulseConfig
from emulator.receiver.quantize import QuantizeConfig, QuantizeEffect
from emulator.scene.tables import (
    MAX_CONTROL_STEPS_PER_EPOCH, MIN_WAYPOINT_DT_S, Posed, ReceiverTable, SceneTable, TableReader, Waypoint,
    toml_document, toml_file,
)
from emulator.scene.types import (
    SPEC_VERSION, Effects, GroundTruthSpec, ReceiverSpec, Scene, Transmitter, arva_labels, truth_streams,
)
from emulator.schema import given, type_name
from emulator.truth.error import GroundTruthErrorConfig

DEFAULT_SCENE = "default.toml"
_EFFECT_CONFIGS = {
    "pulses": PulseConfig,
    "quantize": QuantizeConfig,
    "ground_truth_error": GroundTruthErrorConfig,
    "link_faults": LinkFaultConfig,
}


def parse_scene(data: dict, source: str) -> Scene:
    """Validate a decoded TOML document; ``source`` names it in error messages."""
    rd = TableReader(source)
    spec = rd.version(data, "spec", SPEC_VERSION)
    doc: SceneTable = rd.convert(data, SceneTable, "")
    rx_tables = [(r, f"receivers[{i}]") for i, r in enumerate(doc.receivers or [])] or (
        [(doc.receiver, "receiver")] if doc.receiver else []
    )
    profiles = _profiles(rd, rx_tables)
    rate_hz = doc.rate_hz if doc.rate_hz is not None else _profile_rate(rd, profiles)
    model_keys = given(doc.model)
    model = rd.build("model", ModelParams, **model_keys)

    transmitters = []
    pulse_periods: dict[int, float] = {}
    pulse_phases: dict[int, float] = {}
    seen: dict[int, int] = {}
    for i, tx in enumerate(doc.transmitters):
        path = f"transmitters[{i}]"
        if tx.id in seen:
            raise rd.fail(f"{path}.id", f"duplicate id {tx.id} (also transmitters[{seen[tx.id]}].id)")
        seen[tx.id] = i
        transmitters.append(Transmitter(tx.id, _trajectory(rd, tx, path), tx.gps, tx.attitude))
        for key, target in (("pulse_period_ms", pulse_periods), ("pulse_phase_ms", pulse_phases)):
            if getattr(tx, key) is not None:
                if not doc.effects.pulses:
                    raise rd.fail(f"{path}.{key}", "given but effects.pulses is not enabled")
                target[tx.id] = getattr(tx, key)
    transmitters.sort(key=lambda tx: tx.id)
    effects = _effects(rd, doc, pulse_periods, pulse_phases)

    if doc.receiver is not None and doc.receivers is not None:
        raise rd.fail("receivers", "give either [receiver] or [[receivers]], not both")
    if not rx_tables:
        raise rd.fail("receiver", "missing table")
    receivers = _receivers(rd, rx_tables, rate_hz, profiles, model_keys, doc.effects.quantize is not None)
    for rx in receivers:
        quantize = effects.quantize if rx.display is None else rx.display
        if quantize is not None:
            _check_quantized_range(rd, rx.model or model, quantize)
    if effects.link_fault_streams:
        labels = arva_labels(receivers) + [label for label, _, _ in truth_streams(receivers, transmitters)]
        for i, label in enumerate(effects.link_fault_streams):
            if label not in labels:
                raise rd.fail(f"link_faults.streams[{i}]", f"no stream {label!r} in this scene (streams: {', '.join(labels)})")
    origin, ground_truth = _ground_truth(rd, doc, transmitters, receivers)
    if effects.ground_truth_error is not None and not any(d.gps or d.attitude for d in (*transmitters, *receivers)):
        raise rd.fail("effects.ground_truth_error", "no device has gps or attitude streams to apply it to")
    return Scene(
        source, spec, doc.seed, rate_hz, receivers[0].model or model, effects, tuple(transmitters), receivers, doc.name,
        origin, ground_truth,
    )


def _quaternion(rd: TableReader, q: tuple[float, ...], path: str) -> list[float]:
    try:
        return normalize_quaternions(q, path).tolist()
    except PoseError as exc:
        raise rd.fail(path, exc.reason) from None


def _trajectory(rd: TableReader, pose: Posed, path: str) -> Trajectory:
    if pose.path is not None:
        if pose.position is not None or pose.orientation is not None:
            raise rd.fail(f"{path}.path", "give either position/orientation or path, not both")
        return _waypoints(rd, pose.path, f"{path}.path")
    if pose.position is None:
        raise rd.fail(f"{path}.position", "missing")
    return Trajectory.static(pose.position, _quaternion(rd, pose.orientation or IDENTITY, f"{path}.orientation"))


def _waypoints(rd: TableReader, waypoints: list[Waypoint], path: str) -> Trajectory:
    times = np.array([wp.t for wp in waypoints])
    positions = np.array([wp.position for wp in waypoints])
    for i in range(1, len(waypoints)):
        t, before = times[i], times[i - 1]
        if not t > before:
            raise rd.fail(f"{path}[{i}].t", f"times must increase strictly, {t:g} follows {before:g}")
        if t - before < MIN_WAYPOINT_DT_S:
            raise rd.fail(f"{path}[{i}].t", f"must be at least {MIN_WAYPOINT_DT_S:g} s after {before:g}, got {t:g}")
        with np.errstate(over="ignore"):  # the segment's speed (GPS truth reports it) must be a float
            speed = np.abs(positions[i] - positions[i - 1]) / (t - before)
        if not np.all(np.isfinite(speed)):
            raise rd.fail(f"{path}[{i}].position", "too far from the waypoint before for the time between them "
                          "(the speed is beyond the float range)")
    orientations = [_quaternion(rd, wp.orientation, f"{path}[{i}].orientation") for i, wp in enumerate(waypoints)]
    return Trajectory(times, positions, np.array(orientations))


def _check_quantized_range(rd: TableReader, model: ModelParams, cfg: QuantizeConfig) -> None:
    """The largest reading (r_inner or r_outer, in cm) must still encode once rounded to
    the display steps: rounding is monotone, so checking the largest is enough."""
    largest = int(round(max(model.r_inner, model.r_outer) * 100.0))
    d, _ = QuantizeEffect(cfg).apply(np.array([largest]), np.array([0]), np.array([False]))
    if int(d[0]) > MAX_D_CM:
        key = "quantize.d_step_far_cm" if cfg.d_far_cm is not None and largest >= cfg.d_far_cm else "quantize.d_step_cm"
        raise rd.fail(key, f"the largest reading ({largest} cm, from model.r_inner / r_outer) would round to {int(d[0])} cm, "
                           f"beyond the protocol's {MAX_D_CM}")


def _ground_truth(rd: TableReader, doc: SceneTable, transmitters, receivers) -> tuple[Origin | None, GroundTruthSpec]:
    """``[origin]`` (geodetic, for GPS) and ``[ground_truth]`` (stream settings)."""
    origin = None if doc.origin is None else rd.build("", Origin, **given(doc.origin))
    g = doc.ground_truth
    start = GroundTruthSpec().start_utc if g.start_utc is None else g.start_utc
    if isinstance(start, str):
        try:
            start = _dt.datetime.fromisoformat(start.replace("Z", "+00:00"))
        except ValueError:
            raise rd.fail("ground_truth.start_utc", f"not an ISO 8601 date-time: {start!r}") from None
    if not isinstance(start, _dt.datetime):
        raise rd.fail("ground_truth.start_utc", f"expected a date-time, got {type_name(start)}")
    if start.tzinfo is None:
        raise rd.fail("ground_truth.start_utc", "needs a time zone (e.g. 2026-01-15T10:00:00Z)")
    spec = GroundTruthSpec(start.astimezone(_dt.timezone.utc), g.gps_rate_hz, g.attitude_rate_hz, g.talker, g.lat_lon_decimals)
    if origin is None:
        for kind, device in [("receiver", rx) for rx in receivers] + [("transmitter", tx) for tx in transmitters]:
            if device.gps:
                raise rd.fail("origin", f"missing table: {kind} {device.id} has gps = true, which needs a geodetic origin")
    return origin, spec


def _effects(rd: TableReader, doc: SceneTable, periods: dict, phases: dict) -> Effects:
    """Each enabled effect's config from its own table (``[pulses]``, ``[quantize]`` ...).

    A parameter table for an effect that is not enabled is an error: a scene that sets
    ``[pulses]`` and forgets ``effects.pulses = true`` would otherwise silently differ.
    """
    configs: dict[str, object] = {}
    streams: tuple[str, ...] = ()
    for name, config in _EFFECT_CONFIGS.items():
        table, enabled = getattr(doc, name), bool(getattr(doc.effects, name))
        if table is not None and not enabled:
            raise rd.fail(name, f"parameters given but effects.{name} is not enabled")
        if not enabled:
            continue
        kwargs = given(table) if table is not None else {}
        if name == "link_faults":
            streams = tuple(kwargs.pop("streams", ()))
        if name == "pulses":
            kwargs.update(periods_ms=periods, phases_ms=phases)
        configs[name] = rd.build("", config, **kwargs)
    return Effects(doc.effects.noise, doc.effects.research_sentences, link_fault_streams=streams, **configs)


def _profiles(rd: TableReader, rx_tables: list[tuple[ReceiverTable, str]]) -> list[ReceiverProfile | None]:
    """Each receiver's profile (``profile = "NAME"``), None where it names none."""
    out: list[ReceiverProfile | None] = []
    for table, path in rx_tables:
        try:
            out.append(None if table.profile is None else load_profile(table.profile))
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


def _receivers(
    rd: TableReader, tables: list[tuple[ReceiverTable, str]], rate_hz: float, profiles: list[ReceiverProfile | None],
    model_keys: dict, scene_sets_quantize: bool,
) -> tuple[ReceiverSpec, ...]:
    """``[receiver]`` (one) or ``[[receivers]]`` (several, each on its own port).

    A receiver's ``profile`` gives its class, channels, model constants and display;
    the scene's own keys (``channels``, ``antennas``, ``[model]``, ``effects.quantize``)
    override it."""
    out: list[ReceiverSpec] = []
    seen: dict[int, str] = {}
    for i, ((r, path), profile) in enumerate(zip(tables, profiles)):
        rx_id = i + 1 if r.id is None else r.id
        if rx_id in seen:
            raise rd.fail(f"{path}.id", f"duplicate id {rx_id} (also {seen[rx_id]}.id)")
        seen[rx_id] = path
        channels = r.channels if r.channels is not None else profile.channels if profile else 1
        # Defaults, then the profile, then the scene's [model] keys, then antennas.
        base = profile.model if profile is not None else ModelParams()
        antennas = base.antennas if r.antennas is None else r.antennas
        model = rd.build("model", partial(replace, base), **model_keys, antennas=antennas)  # each within MODEL_LIMITS
        display = profile.display if profile is not None and not scene_sets_quantize else None
        vehicle = _vehicle(rd, r, path, rate_hz) if r.vehicle is not None else None
        trajectory = _trajectory(rd, r, path) if vehicle is None else _start_pose(vehicle)
        out.append(ReceiverSpec(rx_id, channels, trajectory, r.gps, r.attitude, vehicle, model, display,
                                profile.name if profile else ""))
    return tuple(out)


def _vehicle(rd: TableReader, r: ReceiverTable, path: str, rate_hz: float) -> VehicleSpec:
    """``[receiver.vehicle]``: the receiver rides on a vehicle (emulator.closed_loop.vehicle)."""
    for key in ("position", "orientation", "path", "gps", "attitude"):
        if getattr(r, key) not in (None, False):
            why = "its pose comes from the vehicle" if key in ("position", "orientation", "path") else (
                "ground-truth streams are not emulated for a vehicle yet"
            )
            raise rd.fail(f"{path}.{key}", f"not allowed with {path}.vehicle: {why}")
    source = Path(rd.source)
    vehicle = parse_vehicle(rd, r.vehicle, f"{path}.vehicle", source.parent if source.is_file() else None)
    key, got = f"{path}.vehicle.control_rate_hz", vehicle.control_rate_hz
    ratio = got / rate_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise rd.fail(key, f"must be a whole multiple of rate_hz = {rate_hz:g}, got {got:g}")
    if round(ratio) > MAX_CONTROL_STEPS_PER_EPOCH:
        raise rd.fail(key, f"at most {MAX_CONTROL_STEPS_PER_EPOCH} control steps per epoch "
                           f"(rate_hz = {rate_hz:g}), got {got:g} Hz")
    return vehicle


def _start_pose(vehicle: VehicleSpec) -> Trajectory:
    uav = UAV(vehicle.terrain, vehicle.start, vehicle.height_start, vehicle.yaw_deg)
    return Trajectory.static(uav.position, uav.orientation)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file. Every failure is a one-line :class:`SceneError`."""
    return parse_scene(toml_file(path, "scene file"), str(path))


def loads_scene(raw: bytes | str, source: str) -> Scene:
    return parse_scene(toml_document(raw, source), source)


def default_scene() -> Scene:
    """The embedded default: the paper's four case-study transmitters, 4 channels."""
    ref = resources.files("emulator") / "scenes" / DEFAULT_SCENE
    return loads_scene(ref.read_bytes(), f"<embedded {DEFAULT_SCENE}>")
