"""Scenes for the harness as TOML: a dict written with tomli_w (the emulator validates the
result as it validates any scene file), a path, or None (the embedded default)."""

from __future__ import annotations

import itertools
import math
import tomllib
from pathlib import Path
from typing import Any

import tomli_w

_counter = itertools.count()


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


def scene_file(scene, workdir: Path) -> str | None:
    """A path the emulator can read for ``scene``; None for the embedded default."""
    if scene is None:
        return None
    if isinstance(scene, dict):
        path = workdir / f"scene-{next(_counter)}.toml"
        path.write_text(dumps(scene), encoding="utf-8")
        return str(path)
    return str(Path(scene))


def scene_text(path: str | None) -> str:
    """The text of a scene file (None: the embedded default); OSError or
    UnicodeDecodeError (a ValueError) if it cannot be read."""
    if path is None:
        from importlib import resources

        return (resources.files("emulator") / "scenes" / "default.toml").read_text(encoding="utf-8")
    return Path(path).read_text(encoding="utf-8")


def first_receiver_label(path: str | None) -> tuple[int | None, str]:
    """(seed, label of the first receiver's stream) read from a scene file (None: the
    embedded default), without validating it (the emulator does, naming the key)."""
    try:
        data = tomllib.loads(scene_text(path))
    except (OSError, ValueError):
        return None, "arva"
    seed = data.get("seed", 0)
    seed = seed if isinstance(seed, int) and not isinstance(seed, bool) else None
    rxs = data.get("receivers")
    if isinstance(rxs, list) and len(rxs) > 1 and isinstance(rxs[0], dict):
        rx_id = rxs[0].get("id", 1)
        return seed, f"arva:{rx_id}"
    return seed, "arva"
