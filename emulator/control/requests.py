"""Control requests (BRIEF 9): one JSON object per line, decoded into schema structs.

:func:`parse_request` turns one line (bytes, without or with its ``\\n``) into one of the
request structs below (a union tagged by ``op``, :mod:`emulator.schema`), or raises
:class:`ControlError` whose text is the one-line ``error`` of the reply. Values are
validated like scene values: ids are integers in 0..65535, positions three finite numbers
(metres, ENU), orientations four finite numbers ``[w, x, y, z]`` whose norm is at least
1e-9 (normalised here), ``enabled`` a boolean; times are scene seconds / milliseconds.
Unknown keys are errors that name the key.
"""

from __future__ import annotations

import json
from typing import Literal

import msgspec

from firmware_proto.errors import InputError, PoseError
from firmware_proto.sentences import MAX_ID

from emulator.frames.rotation import normalize_quaternions
from emulator.output.link_faults import INJECTABLE
from emulator.schema import Hinted, Int, Number, SchemaError, Strict, Text, Vector3, Vector4, convert, type_name

#: Longest request line accepted, bytes (a request is a few hundred bytes at most).
MAX_LINE = 65536
#: Most epochs one ``step`` may ask for.
MAX_STEP = 1_000_000
#: Longest fault one request may ask for: a day of scene time.
MAX_FAULT_S = 86400.0
#: Most bytes one ``corrupt`` fault may cover.
MAX_CORRUPT_BYTES = 1_000_000

FAULT_KINDS = tuple(sorted(INJECTABLE))


class ControlError(InputError):
    """A request that cannot be served; ``str()`` is the reply's one-line ``error``."""


Id = Int(0, MAX_ID)
Position = Hinted(Vector3, "3 numbers [x, y, z] in metres")
Orientation = Hinted(Vector4, "4 numbers [w, x, y, z]")


class _Request(Strict, tag_field="op"):
    @property
    def op(self) -> str:
        return self.__struct_config__.tag


class Status(_Request, tag="status"):
    pass


class Step(_Request, tag="step"):
    n: Int(1, MAX_STEP) = 1


class Pause(_Request, tag="pause"):
    pass


class Resume(_Request, tag="resume"):
    pass


class SetTransmitter(_Request, tag="set_transmitter"):
    """Any subset of the fields; None = leave as is. An unknown id adds a transmitter
    (then ``position`` is required)."""

    id: Id
    position: Position | None = None
    orientation: Orientation | None = None
    enabled: bool | None = None


class RemoveTransmitter(_Request, tag="remove_transmitter"):
    id: Id


class SetReceiver(_Request, tag="set_receiver"):
    """Pin receiver ``id`` (None: the first) at a pose, or ``path = "resume"``: hand it
    back to its scene path. A pin given only a position keeps the receiver's orientation
    at the next epoch (and vice versa)."""

    id: Id | None = None
    position: Position | None = None
    orientation: Orientation | None = None
    path: Literal["resume"] | None = None


class Fault(_Request, tag="fault"):
    """``kind`` disconnect (``seconds``), stall (``ms``) or corrupt (``bytes``, here
    ``count``) on the stream labelled ``stream``. Seconds and ms are scene time."""

    stream: Text(".", "a stream label (arva, gps:rx ...)") = "arva"
    kind: Literal[FAULT_KINDS] | None = None
    seconds: Number(0.0, MAX_FAULT_S, positive=True, unit="s") | None = None
    ms: Number(0.0, MAX_FAULT_S * 1000.0, positive=True, unit="ms") | None = None
    count: Int(1, MAX_CORRUPT_BYTES) | None = msgspec.field(default=None, name="bytes")


class Truth(_Request, tag="truth"):
    pass


class Quit(_Request, tag="quit"):
    pass


Request = Status | Step | Pause | Resume | SetTransmitter | RemoveTransmitter | SetReceiver | Fault | Truth | Quit
OPS = {t.__struct_config__.tag: t for t in Request.__args__}
_DECODER = msgspec.json.Decoder(Request)


def parse_request(line: bytes | str) -> Request:
    """One request line -> a request struct, or :class:`ControlError`."""
    line = line.encode("utf-8", "surrogatepass") if isinstance(line, str) else line
    if len(line) > MAX_LINE:
        raise ControlError(f"request longer than {MAX_LINE} bytes")
    try:
        return _checked(_DECODER.decode(line))
    except msgspec.ValidationError:
        pass
    except msgspec.DecodeError as exc:  # a number beyond float64 is left to json below
        if not str(exc).startswith("Number out of range"):
            raise _not_json(line, str(exc).removeprefix("JSON is malformed: ")) from None
    try:
        data = json.loads(line)  # what the error is about, inf and huge integers included
    except (ValueError, RecursionError) as exc:
        raise _not_json(line, str(exc).splitlines()[0] if str(exc) else "nested too deeply") from None
    raise _invalid(data)


def _not_json(line: bytes, reason: str) -> ControlError:
    try:
        line.decode("utf-8")
    except UnicodeDecodeError as bad:
        return ControlError(f"request is not UTF-8 (byte offset {bad.start})")
    return ControlError(f"request is not JSON: {reason[:1].lower()}{reason[1:]}")


def _invalid(data: object) -> ControlError:
    """What is wrong with a request that is JSON, in the words of the reply."""
    if not isinstance(data, dict):
        return ControlError(f"request must be a JSON object, got {type_name(data, 'an object')}")
    op = data.get("op")
    if op is None:
        return ControlError('request has no "op"')
    if not isinstance(op, str):
        return ControlError(f'"op" must be a string, got {type_name(op, "an object")}')
    if op not in OPS:
        return ControlError(f"unknown op {op[:40]!r} (known: {', '.join(OPS)})")
    try:
        convert(data, OPS[op], "an object")
    except SchemaError as exc:
        if exc.reason == "unknown key":
            return ControlError(f"{op}: unknown key {exc.key[:40]!r}")
        return ControlError(f"{op}.{exc.key}: {exc.reason}")
    return ControlError(f"{op}: not a valid request")  # json and msgspec disagree (not seen)


def _checked(req: Request) -> Request:
    """The rules across fields: unit quaternions, what a set_receiver or fault needs."""
    op = req.op
    if isinstance(req, (SetTransmitter, SetReceiver)) and req.orientation is not None:
        try:
            q = normalize_quaternions(req.orientation, f"{op}.orientation")
        except PoseError as exc:
            raise ControlError(str(exc)) from None
        req = msgspec.structs.replace(req, orientation=tuple(q.reshape(4).tolist()))
    if isinstance(req, SetReceiver):
        posed = req.position is not None or req.orientation is not None
        if req.path is not None and posed:
            raise ControlError(f'{op}: give either path = "resume" or a position/orientation, not both')
        if req.path is None and not posed:
            raise ControlError(f'{op}: give a position and/or an orientation, or path = "resume"')
    if isinstance(req, Fault):
        if req.kind is None:
            raise ControlError(f"{op}.kind: must be one of {', '.join(FAULT_KINDS)}, got nothing")
        wanted = INJECTABLE[req.kind]  # the parameter it takes
        for key, value in (("seconds", req.seconds), ("ms", req.ms), ("bytes", req.count)):
            if value is not None and key != wanted:
                raise ControlError(f"{op}.{key}: not a parameter of kind {req.kind} (it takes {wanted})")
            if value is None and key == wanted:
                raise ControlError(f"{op}.{key}: missing")
    return req


def encode_reply(reply: dict) -> bytes:
    """A reply object as one JSON line (never NaN/inf: those are not JSON)."""
    return json.dumps(reply, allow_nan=False, separators=(", ", ": ")).encode() + b"\n"


def error_reply(message: str) -> dict:
    return {"ok": False, "error": " ".join(str(message).split())}
