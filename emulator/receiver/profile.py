"""Named receiver profiles: declarative TOML files describing a class of receiver.

A profile (``emulator/receiver/profiles/NAME.toml``, shipped with the package, in the
manner of pyvisa-sim's device files) fixes what a scene would otherwise have to spell
out for a receiver: antennas (2 or 3, :class:`~emulator.receiver.model.ModelParams`),
channels, the epoch rate (Hz), the zone radii and range (``[model]`` r_inner, r_outer,
metres), kappa_eq, the EMI parameters (r_en in metres, q) and the display quantisation
(``[display]``, the keys of a scene's ``[quantize]`` table). A scene selects one with
``[receiver] profile = "NAME"``; every key the scene gives itself overrides the
profile's (see :func:`emulator.scene.reader.parse_scene`).

File format (``format = 1``)::

    format = 1              # profile file format; newer than this program reads: error
    name = "NAME"           # must equal the file name without .toml
    version = 1             # the profile's own revision (integer >= 1)
    description = "one line"
    antennas = 3
    channels = 1
    rate_hz = 1.0
    [model]                 # optional keys: kappa_eq, r_inner, r_outer, r_en, q
    [display]               # optional: profile, delta_step_deg, d_step_cm, d_far_cm, d_step_far_cm

Validation is strict: an unknown key, a wrong type or an out-of-range value raises
:class:`~firmware_proto.errors.SceneError` naming ``FILE: key.path: reason``. The
transmitter's ``moment`` is not a receiver property and is not accepted here.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from firmware_proto.errors import InputError, SceneError
from firmware_proto.sentences import MAX_CHANNELS

from emulator.files import MAX_TOML_BYTES, FileRefused, read_regular
from emulator.receiver.model import ANTENNAS, ModelParams
from emulator.receiver.quantize import QuantizeConfig

#: The newest profile file format this program reads.
PROFILE_FORMAT = 1
#: Epoch rates a profile may give, Hz (the scene reader's limits).
RATE_LIMITS_HZ = (1e-3, 1e4)

_TOP_KEYS = {"format", "name", "version", "description", "antennas", "channels", "rate_hz", "model", "display"}
_MODEL_KEYS = ("kappa_eq", "r_inner", "r_outer", "r_en", "q")
_DISPLAY_KEYS = {"profile": str, "delta_step_deg": int, "d_step_cm": int, "d_far_cm": int, "d_step_far_cm": int}


@dataclass(frozen=True)
class ReceiverProfile:
    """A validated receiver profile. ``model`` has the profile's receiver constants (and
    the default transmitter moment); ``display`` is None for exact integers."""

    name: str
    version: int
    description: str
    source: str
    channels: int
    rate_hz: float
    model: ModelParams
    display: QuantizeConfig | None

    @property
    def antennas(self) -> int:
        return self.model.antennas


def _type_name(value: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "an array",
            dict: "a table"}.get(type(value), type(value).__name__)  # fmt: skip


class _Check:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, reason: str) -> SceneError:
        return SceneError(self.source, key, reason)

    def keys(self, table: dict, path: str, allowed) -> None:
        for key in table:
            if key not in allowed:
                raise self.fail(f"{path}.{key}" if path else key, "unknown key")

    def integer(self, table: dict, key: str, path: str, lo: int, hi: int) -> int:
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"expected an integer, got {_type_name(value)}")
        if not lo <= value <= hi:
            raise self.fail(path, f"must be in {lo}..{hi}, got {value}")
        return value

    def number(self, table: dict, key: str, path: str) -> float:
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(path, f"expected a number, got {_type_name(value)}")
        if not (math.isfinite(value) and value > 0):
            raise self.fail(path, f"must be a finite number > 0, got {value}")
        return float(value)

    def string(self, table: dict, key: str, path: str) -> str:
        value = table[key]
        if not isinstance(value, str):
            raise self.fail(path, f"expected a string, got {_type_name(value)}")
        return value

    def table(self, data: dict, key: str) -> dict:
        value = data.get(key, {})
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {_type_name(value)}")
        return value


def parse_profile(data: dict, source: str, name: str | None = None) -> ReceiverProfile:
    """Validate a decoded profile document; ``name`` (the file stem) must match its ``name``."""
    ck = _Check(source)
    if "format" not in data:
        raise ck.fail("format", f"missing (this program reads format = {PROFILE_FORMAT})")
    fmt = ck.integer(data, "format", "format", 1, 2**31)
    if fmt > PROFILE_FORMAT:
        raise ck.fail("format", f"version {fmt} is newer than this program supports ({PROFILE_FORMAT})")
    ck.keys(data, "", _TOP_KEYS)
    for key in ("name", "version", "description", "antennas", "channels", "rate_hz"):
        if key not in data:
            raise ck.fail(key, "missing")
    prof_name = ck.string(data, "name", "name")
    if name is not None and prof_name != name:
        raise ck.fail("name", f"must equal the file name {name!r}, got {prof_name!r}")
    description = ck.string(data, "description", "description")
    if not description or "\n" in description:
        raise ck.fail("description", "expected one non-empty line")
    version = ck.integer(data, "version", "version", 1, 2**31)
    antennas = ck.integer(data, "antennas", "antennas", min(ANTENNAS), max(ANTENNAS))
    channels = ck.integer(data, "channels", "channels", 1, MAX_CHANNELS)
    rate = ck.number(data, "rate_hz", "rate_hz")
    lo, hi = RATE_LIMITS_HZ
    if not lo <= rate <= hi:
        raise ck.fail("rate_hz", f"must be within [{lo:g}, {hi:g}] Hz, got {rate:g}")

    m = ck.table(data, "model")
    ck.keys(m, "model", _MODEL_KEYS)
    values: dict[str, Any] = {}
    for key in _MODEL_KEYS:
        if key not in m:
            continue
        if key == "q":
            q = m["q"]
            if not isinstance(q, list) or len(q) != 3:
                raise ck.fail("model.q", f"expected an array of 3 numbers, got {_type_name(q)}")
            for i, qi in enumerate(q):
                if isinstance(qi, bool) or not isinstance(qi, (int, float)) or not 0 < qi <= 1:
                    raise ck.fail(f"model.q[{i}]", f"must be a number in (0, 1], got {qi!r}")
            values["q"] = tuple(float(qi) for qi in q)
        else:
            values[key] = ck.number(m, key, f"model.{key}")
    try:
        model = ModelParams(antennas=antennas, **values)
    except InputError as exc:
        raise ck.fail("model", str(exc)) from None

    disp = ck.table(data, "display")
    ck.keys(disp, "display", _DISPLAY_KEYS)
    display = None
    if disp:
        kwargs = {}
        for key, kind in _DISPLAY_KEYS.items():
            if key in disp:
                kwargs[key] = (
                    ck.string(disp, key, f"display.{key}") if kind is str
                    else ck.integer(disp, key, f"display.{key}", 1, 2**31)
                )  # fmt: skip
        try:
            display = QuantizeConfig(**kwargs)
        except InputError as exc:
            raise ck.fail("display", str(exc)) from None
    return ReceiverProfile(prof_name, version, description, source, channels, rate, model, display)


def _profile_dir():
    return resources.files("emulator.receiver") / "profiles"


def profile_names() -> list[str]:
    """Names of the shipped profiles, sorted."""
    return sorted(p.name[: -len(".toml")] for p in _profile_dir().iterdir() if p.name.endswith(".toml"))


def load_profile_file(path: str | Path) -> ReceiverProfile:
    """Read and validate one profile file (its name must match the file name)."""
    path = Path(path)
    try:
        raw = read_regular(path, MAX_TOML_BYTES, "profile file")
    except FileRefused as exc:
        raise SceneError(str(path), "", exc.reason) from None
    return _loads(raw, str(path), path.stem)


def _loads(raw: bytes, source: str, name: str) -> ReceiverProfile:
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneError(source, "", f"not UTF-8 text (byte offset {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"TOML syntax: {exc}") from None
    return parse_profile(data, source, name)


def load_profile(name: str) -> ReceiverProfile:
    """The shipped profile ``name``; :class:`InputError` names the known ones otherwise."""
    names = profile_names()
    if name not in names:
        raise InputError(f"unknown receiver profile {name!r} (known: {', '.join(names)})")
    ref = _profile_dir() / f"{name}.toml"
    return _loads(ref.read_bytes(), f"<profile {name}.toml>", name)


def list_profiles() -> list[ReceiverProfile]:
    return [load_profile(n) for n in profile_names()]


def profile_table() -> str:
    """One line per shipped profile: name, version, antennas, description (for --list-profiles)."""
    profiles = list_profiles()
    width = max((len(p.name) for p in profiles), default=4)
    lines = [f"{'NAME':<{width}}  VERSION  ANTENNAS  DESCRIPTION"]
    for p in profiles:
        lines.append(f"{p.name:<{width}}  {p.version:>7}  {p.antennas:>8}  {p.description}")
    return "\n".join(lines) + "\n"

