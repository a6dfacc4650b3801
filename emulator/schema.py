"""The one schema layer (issue 30): typed structs checked by msgspec, errors in our words.

Scenes, control requests and receiver profiles declare their keys as :class:`Strict`
structs whose fields carry their rules as ``Annotated`` types built here (each value's
rule written once); :func:`convert` turns msgspec's error into :class:`SchemaError`
(``transmitters[0].id``: ``must be in 0..65535, got -3``), which callers wrap in their
own one-line error. Cross-field rules stay with the callers. The choice and the error
mapping: docs/architecture.md "The schema library".
"""

from __future__ import annotations

import datetime
import functools
import json
import math
import operator
import re
import sys
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import inspect as mi

from firmware_proto.errors import InputError

MAX_FLOAT = sys.float_info.max


class Strict(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """Base of every schema struct: an unknown key is an error naming it."""


class SchemaError(InputError):
    """``key`` (``a.b[2].c``, "" for the document) and ``reason``, in our words."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}" if key else reason)
        self.key, self.reason = key, reason


def is_number(value: Any) -> bool:
    """A finite int or float (numpy's too), not a boolean: the check of the effects'
    settings built in code, where no schema has converted them."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) and math.isfinite(value)


def Int(lo: int, hi: int) -> Any:
    """An integer (not a boolean) in lo..hi."""
    return Annotated[int, msgspec.Meta(ge=lo, le=hi)]


def Number(lo: float = -MAX_FLOAT, hi: float = MAX_FLOAT, *, positive: bool = False, unit: str | None = None) -> Any:
    """A finite number in [lo, hi] (``positive``: > 0 instead of >= lo = 0). With a
    ``unit`` (may be "") an error names both bounds: ``must be within [lo, hi] Hz``."""
    meta = msgspec.Meta(gt=lo, le=hi) if positive else msgspec.Meta(ge=lo, le=hi)
    return Annotated[float, meta] if unit is None else Annotated[float, meta, msgspec.Meta(extra={"unit": unit})]


def Text(pattern: str, hint: str) -> Any:
    """A string matching ``pattern``; an error says ``expected HINT, got 'value'``."""
    return Annotated[str, msgspec.Meta(pattern=pattern, extra={"hint": hint})]


def Hinted(type_: Any, hint: str) -> Any:
    """``type_`` whose errors say ``expected HINT, got ...`` (units, layout)."""
    return Annotated[type_, msgspec.Meta(extra={"hint": hint})]


Finite = Number()
Vector2 = tuple[Finite, Finite]
Vector3 = tuple[Finite, Finite, Finite]
Vector4 = tuple[Finite, Finite, Finite, Finite]

#: How a value's type is named in an error (the ``object`` entry is the caller's word).
TYPE_NAMES = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "an array",
              dict: "a table", type(None): "null", datetime.datetime: "a date-time"}
_EXPECTED = {"int": "an integer", "float": "a number", "bool": "true or false", "str": "a string",
             "array": "an array", "object": "a table", "datetime": "a date-time", "null": "null"}
_AT = re.compile(r"\.([^.\[]+)|\[(\d+)\]|\[(\.\.\.)\]")  # [...]: a mapping's key, unnamed


def type_name(value: Any, table: str = "a table") -> str:
    return table if isinstance(value, dict) else TYPE_NAMES.get(type(value), type(value).__name__)


def convert(data: Any, type_: Any, table: str = "a table") -> Any:
    """``data`` as ``type_`` (strict: no str -> number, no number -> bool), or
    :class:`SchemaError`. ``table`` names a mapping in errors ("a table", "an object")."""
    try:
        return msgspec.convert(data, type_, strict=True)
    except msgspec.ValidationError as exc:
        raise explain(str(exc), data, type_, table) from None


def given(table: msgspec.Struct) -> dict:
    """The fields a table gives (None: not given), as keyword arguments."""
    return {k: v for k, v in msgspec.structs.asdict(table).items() if v is not None}


def explain(message: str, data: Any, type_: Any, table: str = "a table") -> SchemaError:
    """msgspec's ``REASON - at `$.PATH``` about ``data`` as ``type_``, in our words."""
    text, _, at = message.partition(" - at `$")
    parts: list[str | int] = [m[1] or m[3] or int(m[2]) for m in _AT.finditer(at.rstrip("`"))]
    _name_keys(message, data, type_, parts)
    field = re.fullmatch(r"Object (missing required|contains unknown) field `(.*)`", text)
    if field:
        return SchemaError(_key([*parts, field[2]]), "missing" if field[1].startswith("missing") else "unknown key")
    value, node = data, mi.type_info(type_)
    for part in parts:
        node = _child(node, value, part)
        try:
            value = value[part]
        except (LookupError, TypeError):
            value = None
    return SchemaError(_key(parts), _reason(text, value, node, table))


def _name_keys(message: str, data: Any, type_: Any, parts: list[str | int]) -> None:
    """Replace each ``...`` in ``parts`` (msgspec does not name a mapping's key) by the key of
    the mapping's first entry failing as ``message`` says: msgspec checks entries in order,
    so the last of the shortest prefix failing so, bisected (log2(entries) conversions)."""
    for i, part in enumerate(parts):
        if part == "...":
            items = list(functools.reduce(operator.getitem, parts[:i], data).items())
            lo, hi = 1, len(items)
            while lo < hi:
                mid = (lo + hi) // 2
                try:
                    msgspec.convert(_put(data, parts[:i], dict(items[:mid])), type_, strict=True)
                    same = False
                except msgspec.ValidationError as exc:
                    same = str(exc) == message
                lo, hi = (lo, mid) if same else (mid + 1, hi)
            parts[i] = items[hi - 1][0]
            data = _put(data, parts[:i], dict(items[hi - 1:hi]))  # its entry alone: for a key deeper


def _put(data: Any, path: list[str | int], value: Any) -> Any:
    """``data`` with the item at ``path`` replaced by ``value``, the containers on the way copied."""
    if not path:
        return value
    copy = list(data) if isinstance(data, (list, tuple)) else dict(data)
    copy[path[0]] = _put(data[path[0]], path[1:], value)
    return copy


def join_key(path: str, key: str) -> str:
    """``path.key`` (``path[0]`` for an index key), or whichever is not empty."""
    return f"{path}{'' if key.startswith('[') else '.'}{key}" if path and key else path or key


def _key(parts: list[str | int]) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in parts).lstrip(".")


def _unwrap(node: Any, value: Any = None) -> tuple[Any, dict]:
    """The type under Metadata and ``| None`` (a tagged union: the struct ``value`` names)."""
    extra: dict = {}
    while True:
        if isinstance(node, mi.Metadata):
            extra.update(node.extra or {})
            node = node.type
        elif isinstance(node, mi.UnionType):
            types = [t for t in node.types if not isinstance(t, mi.NoneType)]
            tagged = [t for t in types if isinstance(t, mi.StructType) and isinstance(value, dict)
                      and t.tag_field is not None and value.get(t.tag_field) == t.tag]
            if not tagged and len(types) != 1:
                return node, extra
            node = (tagged or types)[0]
        else:
            return node, extra


def _child(node: Any, value: Any, part: str | int) -> Any:
    node, _ = _unwrap(node, value)
    if isinstance(node, mi.StructType):
        return next((f.type for f in node.fields if f.encode_name == part), mi.AnyType())
    if isinstance(node, mi.TupleType) and isinstance(part, int) and part < len(node.item_types):
        return node.item_types[part]
    if isinstance(node, (mi.ListType, mi.VarTupleType)):
        return node.item_type
    if isinstance(node, mi.DictType):
        return node.value_type
    return mi.AnyType()


def _reason(text: str, value: Any, node: Any, table: str) -> str:
    node, extra = _unwrap(node, value)
    numbers = isinstance(node, mi.TupleType) and all(isinstance(_unwrap(t)[0], mi.FloatType) for t in node.item_types)
    hint = extra.get("hint")
    m = re.fullmatch(r"Expected `([^`]+)`, got `[^`]+`", text)
    if m:
        expected = " or ".join(_EXPECTED.get(n, n) for n in m[1].split(" | ") if n != "null").replace("a table", table)
        if numbers:
            expected = f"an array of {len(node.item_types)} numbers"
        elif isinstance(node, mi.ListType) and isinstance(_unwrap(node.item_type)[0], mi.StructType):
            expected = "an array of tables"
        return f"expected {hint or expected}, got {type_name(value, table)}"
    m = re.fullmatch(r"Expected `array` of length (\d+), got (\d+)", text)
    if m:
        return f"expected {hint or m[1] + (' numbers' if numbers else ' values')}, got {m[2]}"
    if text.startswith("Expected `array` of length >="):
        return "expected a non-empty array"
    if hint:
        return f"expected {hint}, got {value!r}"
    if isinstance(node, mi.LiteralType):
        shown = json.dumps(value, default=str)[:40]
        if len(node.values) == 1:
            return f"must be {json.dumps(node.values[0])}, got {shown}"
        return f"must be one of {', '.join(map(str, node.values))}, got {shown}"
    if text == "Number out of range":  # JSON: beyond the float range
        return f"must be finite, got {value if isinstance(value, float) else 'a huge integer'}"
    if isinstance(node, (mi.IntType, mi.FloatType)) and isinstance(value, (int, float)):
        return _out_of_range(value, node, extra)
    return text[:1].lower() + text[1:]


def _out_of_range(value: float, node: Any, extra: dict) -> str:
    lo = node.ge if node.gt is None else node.gt
    hi = node.le
    if isinstance(value, float) and not math.isfinite(value):
        return f"must be finite, got {value}"
    if isinstance(node, mi.IntType) and lo is not None and hi is not None:
        return f"must be in {lo}..{hi}, got {value}"
    if "unit" in extra:
        unit = f" {extra['unit']}" if extra["unit"] else ""
        return f"must be within {'(' if node.gt is not None else '['}{_short(lo)}, {_short(hi)}]{unit}, got {value:g}"
    if node.gt is not None and not value > node.gt:
        return f"must be > {node.gt:.10g}, got {value:g}"
    if lo is not None and value < lo:
        return f"must be >= {lo:.10g}, got {value:g}"
    return f"must be <= {hi:.10g}, got {value:g}"


def _short(bound: float) -> str:
    """The shorter exact spelling of a bound: 1e+06, 86400000, 99999.99."""
    return min((f"{bound:.10g}", f"{bound:g}"), key=lambda t: (float(t) != bound, len(t)))
