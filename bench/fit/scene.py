"""``--write-scene FILE``: put the fitted ``[model]`` table where the emulator reads it.

If FILE is an existing scene, its ``[model]`` table is replaced (or inserted before the
first table) and everything else is kept byte for byte; otherwise a minimal scene is
created around it, with the noise effect on (r_en only matters with noise). Either way
the result is loaded with :func:`emulator.scene.reader.load_scene` before we return, and an
existing file is restored if that fails.
"""

from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path

from firmware_proto.errors import InputError

from .result import FitResult
from .table import FitInputError

_HEADER = re.compile(r"^\s*\[{1,2}\s*[^\]]+\]{1,2}\s*(#.*)?$")
_MODEL = re.compile(r"^\s*\[\s*model\s*\]\s*(#.*)?$")
_DOTTED = re.compile(r"^\s*model\s*\.")


def _num(x: float) -> str:
    return repr(float(x))


def model_block(result: FitResult) -> str:
    """The ``[model]`` table for a fit, with the uncertainty in comments."""
    p = result.params
    se = result.se
    today = _dt.date.today().isoformat()

    def pm(name: str, unit: str = "") -> str:
        s = se.get(name)
        return f" +- {s:.3g}{unit} (1 s.e.)" if s is not None and s == s else ""

    lines = [
        f"[model]  # fitted by `arva-bench fit` from {result.source} on {today}",
        f"kappa_eq = {_num(p.kappa_eq)}  #{pm('kappa_eq')}, for moment = 1",
        "moment = 1.0  # only kappa_eq / moment is identifiable from d",
        f"r_inner = {_num(p.r_inner)}",
        f"r_outer = {_num(p.r_outer)}{'  #' + pm('r_outer', ' m') if 'r_outer' in result.free else ''}",
        (
            f"r_en = {_num(p.r_en)}  #{pm('r_en', ' m')}"
            if result.separable
            else "# r_en: not determined by this campaign (see the fit's note): the emulator's default stays"
        ),
        f"q = [{', '.join(_num(v) for v in p.q)}]",
    ]
    return "\n".join(line.rstrip() for line in lines) + "\n"


def _new_scene(block: str, result: FitResult) -> str:
    return (
        f"# A scene with the receiver model fitted by `arva-bench fit` from {result.source}.\n"
        "# Copy the [model] table into your own scenes, or edit the transmitter and receiver below.\n"
        "spec = 1\nseed = 0\nrate_hz = 1.0\n\n"
        f"{block}\n"
        "[effects]\nnoise = true  # r_en is the noise-equivalent distance: it needs the noise effect\n\n"
        "[[transmitters]]\nid = 1\nposition = [0.0, 0.0, -1.0]\n\n"
        f"[receiver]\nchannels = 1\nantennas = {result.params.antennas}\nposition = [20.0, 0.0, 1.0]\n"
    )


def _replace_model(text: str, block: str, path: Path) -> str:
    lines = text.splitlines(keepends=True)
    for i, line in enumerate(lines):
        if _DOTTED.match(line):
            raise FitInputError(f"{path}: line {i + 1}: dotted model.* keys; write the model as a [model] table")
    start = next((i for i, line in enumerate(lines) if _MODEL.match(line)), None)
    if start is None:
        first = next((i for i, line in enumerate(lines) if _HEADER.match(line)), len(lines))
        before = "".join(lines[:first])
        sep = "" if not before or before.endswith("\n\n") else ("\n" if before.endswith("\n") else "\n\n")
        return before + sep + block + "\n" + "".join(lines[first:])
    end = next((j for j in range(start + 1, len(lines)) if _HEADER.match(lines[j])), len(lines))
    # Keep blank lines and comments that lead into the next table with it.
    while end > start + 1 and (lines[end - 1].strip() == "" or lines[end - 1].lstrip().startswith("#")):
        end -= 1
    tail = "".join(lines[end:])
    return "".join(lines[:start]) + block + ("\n" + tail.lstrip("\n") if tail else "")


def write_scene(path: str | Path, result: FitResult) -> str:
    """Write or update the scene at ``path``; returns "updated" or "created"."""
    from emulator.scene.reader import load_scene

    path = Path(path)
    block = model_block(result)
    old: str | None = None
    if path.exists():
        try:
            old = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise FitInputError(f"{path}: cannot read the scene to update: {exc}") from None
        text = _replace_model(old, block, path)
    else:
        text = _new_scene(block, result)
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise FitInputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        scene = load_scene(path)
        if scene.receiver_model().antennas != result.params.antennas:
            raise InputError(f"its receiver has {scene.receiver_model().antennas} antennas, the fit assumed "
                             f"{result.params.antennas} (--antennas); set [receiver] antennas")  # fmt: skip
    except InputError as exc:
        if old is not None:
            path.write_text(old, encoding="utf-8")
        else:
            path.unlink(missing_ok=True)
        raise FitInputError(f"{path}: the scene would not load: {exc}") from None
    return "updated" if old is not None else "created"
