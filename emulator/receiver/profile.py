"""Named receiver profiles: declarative TOML files describing a class of receiver.

A profile (``emulator/receiver/profiles/NAME.toml``, its keys :class:`ProfileTable`) fixes
what a scene would otherwise spell out for a receiver; a scene selects one with
``[receiver] profile = "NAME"`` and every key it gives itself wins (docs/model.md
section 9). Units: rate in Hz, radii and r_en in metres. Validation is strict
(:class:`~firmware_proto.errors.SceneError`, ``FILE: key.path: reason``); the
transmitter's ``moment`` is not a receiver property and is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from firmware_proto.errors import InputError
from firmware_proto.sentences import MAX_CHANNELS

from emulator.receiver.model import ANTENNAS, ModelParams
from emulator.receiver.quantize import QuantizeConfig
from emulator.scene.tables import ProfileModelTable, QuantizeTable, Rate, TableReader, toml_document, toml_file
from emulator.schema import Int, Strict, Text, given

#: The newest profile file format this program reads.
PROFILE_FORMAT = 1


class ProfileTable(Strict):
    """A profile file: ``format`` at most :data:`PROFILE_FORMAT`, ``name`` the file's stem."""

    format: int
    name: str
    version: Int(1, 2**31)  # the profile's own revision
    description: Text(r"\A[^\n]+\Z", "one non-empty line")
    antennas: Int(min(ANTENNAS), max(ANTENNAS))
    channels: Int(1, MAX_CHANNELS)
    rate_hz: Rate
    model: ProfileModelTable = ProfileModelTable()
    display: QuantizeTable | None = None


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


def parse_profile(data: dict, source: str, name: str | None = None) -> ReceiverProfile:
    """Validate a decoded profile document; ``name`` (the file stem) must match its ``name``."""
    rd = TableReader(source)
    rd.version(data, "format", PROFILE_FORMAT)
    doc: ProfileTable = rd.convert(data, ProfileTable, "")
    if name is not None and doc.name != name:
        raise rd.fail("name", f"must equal the file name {name!r}, got {doc.name!r}")
    model = rd.build("model", ModelParams, antennas=doc.antennas, **given(doc.model))
    display = None if doc.display is None else rd.build("display", QuantizeConfig, **given(doc.display))
    return ReceiverProfile(doc.name, doc.version, doc.description, source, doc.channels, doc.rate_hz, model, display)


def _profile_dir():
    return resources.files("emulator.receiver") / "profiles"


def profile_names() -> list[str]:
    """Names of the shipped profiles, sorted."""
    return sorted(p.name[: -len(".toml")] for p in _profile_dir().iterdir() if p.name.endswith(".toml"))


def load_profile_file(path: str | Path) -> ReceiverProfile:
    """Read and validate one profile file (its name must match the file name)."""
    return parse_profile(toml_file(path, "profile file"), str(path), Path(path).stem)


def load_profile(name: str) -> ReceiverProfile:
    """The shipped profile ``name``; :class:`InputError` names the known ones otherwise."""
    names = profile_names()
    if name not in names:
        raise InputError(f"unknown receiver profile {name!r} (known: {', '.join(names)})")
    ref = _profile_dir() / f"{name}.toml"
    return parse_profile(toml_document(ref.read_bytes(), f"<profile {name}.toml>"), f"<profile {name}.toml>", name)


def profile_table() -> str:
    """One line per shipped profile: name, version, antennas, description (for --list-profiles)."""
    profiles = [load_profile(n) for n in profile_names()]
    width = max((len(p.name) for p in profiles), default=4)
    lines = [f"{'NAME':<{width}}  VERSION  ANTENNAS  DESCRIPTION"]
    for p in profiles:
        lines.append(f"{p.name:<{width}}  {p.version:>7}  {p.antennas:>8}  {p.description}")
    return "\n".join(lines) + "\n"

