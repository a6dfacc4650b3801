"""Which schema library for the one schema layer (issue 30): msgspec or pydantic v2,
measured on the two hot validations: a control request line (JSON -> typed request, the
control round trip's parse) and a scene's receiver/transmitter tables (decoded TOML dict
-> typed structs). Each library gets the same typed model with the same range rules;
the project's own parsers are measured beside them (hand-written until the migration to
msgspec of issue 30; since then emulator.schema's). Prints microseconds per call
(median of 7 repeats) and the error text each gives for the same bad input.

Run: python tests/perf/schema_choice.py   (needs `pip install msgspec pydantic`)
"""

from __future__ import annotations

import argparse
import statistics
import sys
import timeit
import tomllib
from pathlib import Path
from typing import Annotated, Literal, Union

import msgspec

if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="Needs pydantic: pip install pydantic").parse_args()
try:
    import pydantic
except ImportError:
    raise SystemExit("schema_choice.py: this comparison needs pydantic v2 (pip install pydantic); msgspec alone is the project's") from None

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from emulator.control.requests import parse_request  # noqa: E402
from emulator.scene.reader import loads_scene  # noqa: E402

LINES = [b'{"op": "step", "n": 10}', b'{"op": "set_transmitter", "id": 3, "position": [1.5, -2.0, 0.0], "enabled": true}',
         b'{"op": "fault", "stream": "arva", "kind": "stall", "ms": 250}']
BAD = b'{"op": "step", "n": "ten"}'

# --- msgspec ---------------------------------------------------------------------------
Id = Annotated[int, msgspec.Meta(ge=0, le=65535)]
Finite = float


class MStep(msgspec.Struct, tag="step", tag_field="op", forbid_unknown_fields=True):
    n: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] = 1


class MSetTx(msgspec.Struct, tag="set_transmitter", tag_field="op", forbid_unknown_fields=True):
    id: Id
    position: tuple[Finite, Finite, Finite] | None = None
    orientation: tuple[Finite, Finite, Finite, Finite] | None = None
    enabled: bool | None = None


class MFault(msgspec.Struct, tag="fault", tag_field="op", forbid_unknown_fields=True):
    kind: Literal["disconnect", "stall", "corrupt"]
    stream: str = "arva"
    seconds: Annotated[float, msgspec.Meta(gt=0, le=86400)] | None = None
    ms: Annotated[float, msgspec.Meta(gt=0, le=86400e3)] | None = None
    bytes: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] | None = None


MRequest = Union[MStep, MSetTx, MFault]
m_decoder = msgspec.json.Decoder(MRequest)

# --- pydantic --------------------------------------------------------------------------
Strict = pydantic.ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)
P3 = Annotated[list[float], pydantic.Field(min_length=3, max_length=3)]  # strict: a TOML/JSON array is a list
P4 = Annotated[list[float], pydantic.Field(min_length=4, max_length=4)]


class PStep(pydantic.BaseModel):
    model_config = Strict
    op: Literal["step"]
    n: Annotated[int, pydantic.Field(ge=1, le=1_000_000)] = 1


class PSetTx(pydantic.BaseModel):
    model_config = Strict
    op: Literal["set_transmitter"]
    id: Annotated[int, pydantic.Field(ge=0, le=65535)]
    position: P3 | None = None
    orientation: P4 | None = None
    enabled: bool | None = None


class PFault(pydantic.BaseModel):
    model_config = Strict
    op: Literal["fault"]
    kind: Literal["disconnect", "stall", "corrupt"]
    stream: str = "arva"
    seconds: Annotated[float, pydantic.Field(gt=0, le=86400)] | None = None
    ms: Annotated[float, pydantic.Field(gt=0, le=86400e3)] | None = None
    bytes: Annotated[int, pydantic.Field(ge=1, le=1_000_000)] | None = None


p_adapter = pydantic.TypeAdapter(Annotated[Union[PStep, PSetTx, PFault], pydantic.Field(discriminator="op")])

# --- scene tables ------------------------------------------------------------------------
SCENE = """
spec = 1
rate_hz = 1.0
""" + "".join(f"""
[[transmitters]]
id = {i}
position = [{i * 3.0}, {-i * 2.0}, -1.0]
orientation = [1.0, 0.0, 0.0, 0.0]
""" for i in range(1, 9)) + """
[receiver]
channels = 3
path = [""" + ", ".join(f"{{t = {t}.0, position = [{t * 0.5}, 0.0, 0.0]}}" for t in range(60)) + """]
"""
DATA = tomllib.loads(SCENE)


class MTx(msgspec.Struct, forbid_unknown_fields=True):
    id: Id
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


class MWaypoint(msgspec.Struct, forbid_unknown_fields=True):
    t: Annotated[float, msgspec.Meta(ge=0)]
    position: tuple[float, float, float]


class MRx(msgspec.Struct, forbid_unknown_fields=True):
    channels: Annotated[int, msgspec.Meta(ge=1, le=3)] = 3
    path: list[MWaypoint] = []


class MScene(msgspec.Struct, forbid_unknown_fields=True):
    spec: Literal[1]
    rate_hz: Annotated[float, msgspec.Meta(ge=1e-3, le=1e4)]
    transmitters: list[MTx]
    receiver: MRx


class PTx(pydantic.BaseModel):
    model_config = Strict
    id: Annotated[int, pydantic.Field(ge=0, le=65535)]
    position: P3
    orientation: P4 = [1.0, 0.0, 0.0, 0.0]


class PWaypoint(pydantic.BaseModel):
    model_config = Strict
    t: Annotated[float, pydantic.Field(ge=0)]
    position: P3


class PRx(pydantic.BaseModel):
    model_config = Strict
    channels: Annotated[int, pydantic.Field(ge=1, le=3)] = 3
    path: list[PWaypoint] = []


class PScene(pydantic.BaseModel):
    model_config = Strict
    spec: Literal[1]
    rate_hz: Annotated[float, pydantic.Field(ge=1e-3, le=1e4)]
    transmitters: list[PTx]
    receiver: PRx


def per_call_us(fn, number: int) -> float:
    runs = timeit.repeat(fn, number=number, repeat=7)
    return statistics.median(runs) / number * 1e6


def error_of(fn) -> str:
    try:
        fn()
    except Exception as exc:  # noqa: BLE001 - we print what each library says
        return " ".join(str(exc).split())[:110]
    return "(accepted)"


def main() -> int:
    rows = [
        ("control line -> request", "the project's parse_request", per_call_us(lambda: [parse_request(x) for x in LINES], 3000) / 3),
        ("control line -> request", f"msgspec {msgspec.__version__}", per_call_us(lambda: [m_decoder.decode(x) for x in LINES], 3000) / 3),
        ("control line -> request", f"pydantic {pydantic.VERSION}", per_call_us(lambda: [p_adapter.validate_json(x) for x in LINES], 3000) / 3),
        ("scene dict -> structs (8 tx, 60 waypoints)", f"msgspec {msgspec.__version__}", per_call_us(lambda: msgspec.convert(DATA, MScene), 500)),
        ("scene dict -> structs (8 tx, 60 waypoints)", f"pydantic {pydantic.VERSION}", per_call_us(lambda: PScene.model_validate(DATA), 500)),
        ("scene text -> Scene (whole loader, for scale)", "the project's loads_scene", per_call_us(lambda: loads_scene(SCENE, "s.toml"), 50)),
    ]
    print("| validation | by | us per call |\n|---|---|---|")
    for what, by, us in rows:
        print(f"| {what} | {by} | {us:.1f} |")
    print()
    print("Error for", BAD.decode())
    print("  project:", error_of(lambda: parse_request(BAD)))
    print("  msgspec:     ", error_of(lambda: m_decoder.decode(BAD)))
    print("  pydantic:    ", error_of(lambda: p_adapter.validate_json(BAD)))
    bad_scene = {**DATA, "receiver": {**DATA["receiver"], "path": [*DATA["receiver"]["path"][:3], {"t": 4.0, "position": [0.0, "x", 0.0]}]}}
    print("Error for receiver.path[3].position[1] = 'x'")
    print("  msgspec:     ", error_of(lambda: msgspec.convert(bad_scene, MScene)))
    print("  pydantic:    ", error_of(lambda: PScene.model_validate(bad_scene)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
