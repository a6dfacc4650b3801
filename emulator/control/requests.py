"""Control requests (BRIEF 9): one JSON object per line, parsed into dataclasses.

:func:`parse_request` turns one line (bytes, without or with its ``\\n``) into one of the
request dataclasses below, or raises :class:`ControlError` whose text is the one-line
``error`` of the reply. Values are validated like scene values: ids are integers in
0..65535, positions three finite numbers (metres, ENU), orientations four finite numbers
``[w, x, y, z]`` whose norm is at least 1e-9 (normalised here), ``enabled`` a boolean;
times are scene seconds / milliseconds. Unknown keys are errors that name the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from firmware_proto.errors import InputError, PoseError
from firmware_proto.sentences import MAX_ID

from emulator.frames.rotation import normalize_quaternions

#: Longest request line accepted, bytes (a request is a few hundred bytes at most).
MAX_LINE = 65536
#: Most epochs one ``step`` may ask for.
MAX_STEP = 1_000_000
#: Longest fault one request may ask for: a day of scene time.
MAX_FAULT_S = 86400.0
#: Most bytes one ``corrupt`` fault may cover.
MAX_CORRUPT_BYTES = 1_000_000

FAULT_KINDS = ("disconnect", "stall", "corrupt")


class ControlError(InputError):
    """A request that cannot be served; ``str()`` is the reply's one-line ``error``."""


Vector3 = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]


@dataclass(frozen=True)
class Status:
    op = "status"


@dataclass(frozen=True)
class Step:
    n: int = 1
    op = "step"


@dataclass(frozen=True)
class Pause:
    op = "pause"


@dataclass(frozen=True)
class Resume:
    op = "resume"


@dataclass(frozen=True)
class SetTransmitter:
    """Any subset of the fields; None = leave as is. An unknown id adds a transmitter
    (then ``position`` is required)."""

    id: int
    position: Vector3 | None = None
    orientation: Quaternion | None = None
    enabled: bool | None = None
    op = "set_transmitter"


@dataclass(frozen=True)
class RemoveTransmitter:
    id: int
    op = "remove_transmitter"


@dataclass(frozen=True)
class SetReceiver:
    """Pin receiver ``id`` (None: the first) at a pose, or ``resume_path``: hand it back
    to its scene path. A pin given only a position keeps the receiver's orientation at
    the next epoch (and vice versa)."""

    id: int | None = None
    position: Vector3 | None = None
    orientation: Quaternion | None = None
    resume_path: bool = False
    op = "set_receiver"


@dataclass(frozen=True)
class Fault:
    """``kind`` disconnect (``seconds``), stall (``ms``) or corrupt (``count`` bytes)
    on the stream labelled ``stream``. Seconds and ms are scene time."""

    stream: str
    kind: str
    seconds: float = 0.0
    ms: float = 0.0
    count: int = 0
    op = "fault"


@dataclass(frozen=True)
class Truth:
    op = "truth"


@dataclass(frozen=True)
class Quit:
    op = "quit"


Request = Status | Step | Pause | Resume | SetTransmitter | RemoveTransmitter | SetReceiver | Fault | Truth | Quit


def parse_request(line: bytes | str) -> Request:
    """One request line -> a request dataclass, or :class:`ControlError`."""
    if isinstance(line, bytes):
        if len(line) > MAX_LINE:
            raise ControlError(f"request longer than {MAX_LINE} bytes")
        try:
            line = line.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ControlError(f"request is not UTF-8 (byte offset {exc.start})") from None
    try:
        data = json.loads(line, parse_constant=_reject_constant)
    except ControlError:
        raise
    except (ValueError, RecursionError) as exc:
        raise ControlError(f"request is not JSON: {_first_line(exc)}") from None
    if not isinstance(data, dict):
        raise ControlError(f"request must be a JSON object, got {_type_name(data)}")
    op = data.get("op")
    if op is None:
        raise ControlError('request has no "op"')
    if not isinstance(op, str):
        raise ControlError(f'"op" must be a string, got {_type_name(op)}')
    parser = _PARSERS.get(op)
    if parser is None:
        raise ControlError(f"unknown op {op[:40]!r} (known: {', '.join(_PARSERS)})")
    keys, build = parser
    for key in data:
        if key != "op" and key not in keys:
            raise ControlError(f"{op}: unknown key {str(key)[:40]!r}")
    return build(data)


def _reject_constant(name: str) -> Any:
    raise ControlError(f"request is not JSON: {name} is not a number")


def _first_line(exc: Exception) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _type_name(value: Any) -> str:
    return {
        bool: "a boolean", int: "an integer", float: "a number", str: "a string",
        list: "an array", dict: "an object", type(None): "null",
    }.get(type(value), type(value).__name__)


def _integer(data: dict, key: str, op: str, lo: int, hi: int, default: int | None = None) -> int:
    value = data.get(key, default)
    if value is None:
        raise ControlError(f"{op}.{key}: missing")
    if isinstance(value, bool) or not isinstance(value, int):
        raise ControlError(f"{op}.{key}: expected an integer, got {_type_name(value)}")
    if not lo <= value <= hi:
        raise ControlError(f"{op}.{key}: must be in {lo}..{hi}, got {value}")
    return value


def _number(data: dict, key: str, op: str, lo: float, hi: float, lo_open: bool = False) -> float:
    if key not in data:
        raise ControlError(f"{op}.{key}: missing")
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ControlError(f"{op}.{key}: expected a number, got {_type_name(value)}")
    value = _finite(value, f"{op}.{key}")
    if (value <= lo if lo_open else value < lo) or value > hi:
        bound = f"> {lo:g}" if lo_open else f">= {lo:g}"
        raise ControlError(f"{op}.{key}: must be {bound} and <= {hi:g}, got {value:g}")
    return value


def _vector(value: Any, key: str, op: str) -> Vector3:
    if not isinstance(value, list) or len(value) != 3:
        what = f"{len(value)} numbers" if isinstance(value, list) else _type_name(value)
        raise ControlError(f"{op}.{key}: expected 3 numbers [x, y, z] in metres, got {what}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ControlError(f"{op}.{key}[{i}]: expected a number, got {_type_name(v)}")
        out.append(_finite(v, f"{op}.{key}[{i}]"))
    return (out[0], out[1], out[2])


def _quaternion(value: Any, key: str, op: str) -> Quaternion:
    if not isinstance(value, list) or len(value) != 4:
        what = f"{len(value)} numbers" if isinstance(value, list) else _type_name(value)
        raise ControlError(f"{op}.{key}: expected 4 numbers [w, x, y, z], got {what}")
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ControlError(f"{op}.{key}[{i}]: expected a number, got {_type_name(v)}")
    comps = [_finite(v, f"{op}.{key}[{i}]") for i, v in enumerate(value)]
    try:
        q = normalize_quaternions(comps, f"{op}.{key}")
    except PoseError as exc:
        raise ControlError(str(exc)) from None
    w, x, y, z = (float(c) for c in q.reshape(4))
    return (w, x, y, z)


def _finite(value: int | float, where: str) -> float:
    try:
        out = float(value)  # an integer beyond the float range overflows here
    except OverflowError:
        out = math.inf
    if not math.isfinite(out):
        raise ControlError(f"{where}: must be finite, got {value if isinstance(value, float) else 'a huge integer'}")
    return out


def _optional(data: dict, key: str, parse, op: str):
    return parse(data[key], key, op) if key in data else None


def _set_transmitter(data: dict) -> SetTransmitter:
    op = "set_transmitter"
    enabled = data.get("enabled")
    if enabled is not None and not isinstance(enabled, bool):
        raise ControlError(f"{op}.enabled: expected true or false, got {_type_name(enabled)}")
    if "enabled" in data and enabled is None:
        raise ControlError(f"{op}.enabled: expected true or false, got null")
    return SetTransmitter(
        _integer(data, "id", op, 0, MAX_ID),
        _optional(data, "position", _vector, op),
        _optional(data, "orientation", _quaternion, op),
        enabled,
    )


def _set_receiver(data: dict) -> SetReceiver:
    op = "set_receiver"
    rx_id = _integer(data, "id", op, 0, MAX_ID) if "id" in data else None
    if "path" in data:
        if data["path"] != "resume":
            raise ControlError(f'{op}.path: the only value is "resume", got {json.dumps(data["path"])[:40]}')
        if "position" in data or "orientation" in data:
            raise ControlError(f'{op}: give either path = "resume" or a position/orientation, not both')
        return SetReceiver(rx_id, resume_path=True)
    if "position" not in data and "orientation" not in data:
        raise ControlError(f'{op}: give a position and/or an orientation, or path = "resume"')
    return SetReceiver(rx_id, _optional(data, "position", _vector, op), _optional(data, "orientation", _quaternion, op))


def _fault(data: dict) -> Fault:
    op = "fault"
    stream = data.get("stream", "arva")
    if not isinstance(stream, str) or not stream:
        raise ControlError(f"{op}.stream: expected a stream label (arva, gps:rx ...), got {_type_name(stream)}")
    kind = data.get("kind")
    if kind not in FAULT_KINDS:
        shown = json.dumps(kind)[:40] if kind is not None else "nothing"
        raise ControlError(f"{op}.kind: must be one of {', '.join(FAULT_KINDS)}, got {shown}")
    wanted = {"disconnect": "seconds", "stall": "ms", "corrupt": "bytes"}[kind]
    for key in ("seconds", "ms", "bytes"):
        if key in data and key != wanted:
            raise ControlError(f"{op}.{key}: not a parameter of kind {kind} (it takes {wanted})")
    if kind == "disconnect":
        return Fault(stream, kind, seconds=_number(data, "seconds", op, 0.0, MAX_FAULT_S, lo_open=True))
    if kind == "stall":
        return Fault(stream, kind, ms=_number(data, "ms", op, 0.0, MAX_FAULT_S * 1000.0, lo_open=True))
    return Fault(stream, kind, count=_integer(data, "bytes", op, 1, MAX_CORRUPT_BYTES))


_PARSERS: dict[str, tuple[set[str], Any]] = {
    "status": (set(), lambda d: Status()),
    "step": ({"n"}, lambda d: Step(_integer(d, "n", "step", 1, MAX_STEP, default=1))),
    "pause": (set(), lambda d: Pause()),
    "resume": (set(), lambda d: Resume()),
    "set_transmitter": ({"id", "position", "orientation", "enabled"}, _set_transmitter),
    "remove_transmitter": ({"id"}, lambda d: RemoveTransmitter(_integer(d, "id", "remove_transmitter", 0, MAX_ID))),
    "set_receiver": ({"id", "position", "orientation", "path"}, _set_receiver),
    "fault": ({"stream", "kind", "seconds", "ms", "bytes"}, _fault),
    "truth": (set(), lambda d: Truth()),
    "quit": (set(), lambda d: Quit()),
}


def encode_reply(reply: dict) -> bytes:
    """A reply object as one JSON line (never NaN/inf: those are not JSON)."""
    return json.dumps(reply, allow_nan=False, separators=(", ", ": ")).encode() + b"\n"


def error_reply(message: str) -> dict:
    return {"ok": False, "error": " ".join(str(message).split())}
