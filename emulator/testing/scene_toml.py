"""Write a scene given as a dict (the TOML structure of BRIEF 5) as TOML text.

Enough TOML for scenes: tables, arrays of tables, arrays of numbers / strings /
inline tables (path waypoints), strings, booleans, integers, floats. The emulator
validates the result as it validates any scene file.
"""

from __future__ import annotations

import math
from typing import Any


def dumps(scene: dict) -> str:
    """``scene`` as TOML text; ValueError for values TOML cannot carry."""
    if not isinstance(scene, dict):
        raise ValueError(f"a scene must be a dict, got {type(scene).__name__}")
    lines: list[str] = []
    _table(scene, "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _table(data: dict, prefix: str, lines: list[str]) -> None:
    plain = [(k, v) for k, v in data.items() if not isinstance(v, dict) and not _is_table_array(v)]
    nested = [(k, v) for k, v in data.items() if isinstance(v, dict)]
    arrays = [(k, v) for k, v in data.items() if _is_table_array(v)]
    if prefix and (plain or not (nested or arrays)):
        lines.append(f"\n[{prefix}]")
    for k, v in plain:
        lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in nested:
        _table(v, f"{prefix}.{_key(k)}" if prefix else _key(k), lines)
    for k, v in arrays:
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        for item in v:
            lines.append(f"\n[[{name}]]")
            # Keys first (an array of tables inside an item, like a path's waypoints, is
            # written inline), then the item's sub-tables: a key after a table header
            # would belong to that table.
            for ik, iv in item.items():
                if not isinstance(iv, dict):
                    lines.append(f"{_key(ik)} = {_value(iv)}")
            for ik, iv in item.items():
                if isinstance(iv, dict):
                    _table(iv, f"{name}.{_key(ik)}", lines)


_BARE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")


def _key(k: Any) -> str:
    if not isinstance(k, str):
        k = str(k)
    if k and all(c in _BARE for c in k):  # TOML bare keys: ASCII letters, digits, _ and -
        return k
    return _string(k)


def _string(text: str) -> str:
    """A TOML basic string: quote, backslash and control characters (but tab) escaped."""
    out = ['"']
    for ch in text:
        code = ord(ch)
        if ch in '"\\':
            out.append("\\" + ch)
        elif (code < 0x20 and ch != "\t") or code == 0x7F:
            out.append(f"\\u{code:04X}")
        elif 0xD800 <= code <= 0xDFFF:
            raise ValueError(f"a TOML string cannot hold the lone surrogate U+{code:04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"TOML scene values must be finite, got {v}")
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    if hasattr(v, "isoformat"):
        return v.isoformat()
    raise ValueError(f"cannot write {type(v).__name__} {v!r} as a TOML scene value")
