"""``--write-scene FILE``: put the fitted ``[model]`` table where the emulator reads it.

If FILE is an existing scene, its ``[model]`` table is replaced (or inserted before the
first table) and everything else is kept byte for byte; otherwise a minimal scene is
created around it, with the noise effect on (r_en only matters with noise). Either way
the result is loaded with :func:`emulator.scene.reader.load_scene` before we return, and an
existing file is restored if that fails.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import tomlkit
from tomlkit.items import AoT, Comment, Null, Table, Whitespace

from firmware_proto.errors import InputError

from .result import FitResult
from .table import FitInputError


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
    """``text`` with its model replaced by ``block``, through tomlkit (every other byte
    kept). A ``[model]`` table is replaced where it stands (the comments and blank lines
    leading into the next table stay); a model given as dotted ``model.*`` keys or an
    inline ``model = {...}`` table is removed and ``block`` inserted before the first
    table, as when there is no model."""
    try:
        doc = tomlkit.parse(text)
    except tomlkit.exceptions.ParseError as exc:
        raise FitInputError(f"{path}: the scene would not load: {exc}") from None
    model = tomlkit.parse(block)["model"]
    entries = [(k, v) for k, v in doc.body if k is not None and k.key == "model"]
    if len(entries) == 1 and isinstance(entries[0][1], Table) and not entries[0][1].is_super_table():
        body = entries[0][1].value.body
        lead = len(body)
        while lead and body[lead - 1][0] is None and isinstance(body[lead - 1][1], (Comment, Whitespace)):
            lead -= 1
        for _, item in body[lead:]:
            model.add(item)
        model.add(Whitespace(""))  # ends in whitespace: tomlkit adds no blank line of its own
        doc["model"] = model
        return doc.as_string()
    if entries:
        del doc["model"]
    return _before_first_table(doc, model).as_string()


def _before_first_table(doc: tomlkit.TOMLDocument, model: Table) -> tomlkit.TOMLDocument:
    """A copy of ``doc`` with ``model`` inserted before its first table and the comments
    leading into it, with a blank line on either side."""
    body = [(k, v) for k, v in doc.body if not isinstance(v, Null)]  # Null: a removed key
    start = next((i for i, (_, v) in enumerate(body) if isinstance(v, (Table, AoT))), len(body))
    while start and body[start - 1][0] is None:  # comments and blank lines leading into it
        start -= 1
    blank = start
    while blank < len(body) and isinstance(body[blank][1], Whitespace):
        blank += 1
    before = [(None, Whitespace("\n"))] if blank == start and blank else []
    after = [(None, Whitespace("\n"))] if blank < len(body) else []
    out = tomlkit.document()
    out.parsing(True)  # the items keep their own layout
    for key, item in body[:blank] + before + [("model", model)] + after + body[blank:]:
        if key is None:
            out.add(item)
        else:
            out.append(key, item)
    out.parsing(False)
    return out


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
