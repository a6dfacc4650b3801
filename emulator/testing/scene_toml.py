"""Write a scene given as a dict (the TOML structure of BRIEF 5) as TOML text, with
tomli_w. The emulator validates the result as it validates any scene file."""

from __future__ import annotations

import math
from typing import Any

import tomli_w


def dumps(scene: dict) -> str:
    """``scene`` as TOML text; ValueError for values TOML cannot carry (None, NaN,
    infinities, lone surrogates, other types)."""
    if not isinstance(scene, dict):
        raise ValueError(f"a scene must be a dict, got {type(scene).__name__}")
    _check_finite(scene)
    try:
        text = tomli_w.dumps(scene)
    except TypeError as exc:
        raise ValueError(f"cannot write the scene as TOML: {exc}") from None
    text.encode("utf-8")  # UnicodeEncodeError (a ValueError) for a lone surrogate
    return text


def _check_finite(value: Any) -> None:
    """ValueError for a NaN or infinity anywhere in ``value`` (tomli_w would write ``nan``)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"TOML scene values must be finite, got {value}")
    items = value.values() if isinstance(value, dict) else value if isinstance(value, (list, tuple)) else ()
    for item in items:
        _check_finite(item)
