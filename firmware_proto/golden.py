"""Golden vectors (``firmware_proto/vectors/*.json``): loading, JSON <-> events, and the
canonical text both implementations are compared in.

``decode.json`` cases: ``input`` is the byte string (each character U+0000..U+00FF stands
for one byte, so JSON escapes like ``\\u00ff`` are raw bytes); ``events`` are what
``feed(input)`` then ``flush()`` return, in order; ``stats`` the counters afterwards.
``expect_fields`` (optional, default false) is the decoder option of the same name.

``encode.json`` cases: ``sentence`` is ``parva`` (args seq, n, k, id, d, delta), ``parvh``
(seq, k, id, hx, hy, hz; components formatted ``%.6e``) or ``epoch`` (seq, slots);
``bytes`` is the exact output, or ``null`` when the encoder must refuse.

Run ``python -m firmware_proto.golden c-table firmware_proto/c/vectors.inc`` to regenerate
the table the C runner (``firmware_proto/c/test_vectors.c``) compiles in.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .events import DecodeError, DecoderStats, Epoch, ErrorKind, Event, Parva, Parvh

VECTORS_DIR = Path(__file__).resolve().parent / "vectors"
C_TABLE = Path(__file__).resolve().parent / "c" / "vectors.inc"


def load(name: str) -> list[dict[str, Any]]:
    """The ``cases`` of ``vectors/<name>.json``."""
    return json.loads((VECTORS_DIR / f"{name}.json").read_text())["cases"]


def to_bytes(text: str) -> bytes:
    return text.encode("latin-1")


def from_bytes(data: bytes) -> str:
    return data.decode("latin-1")


# -- events <-> JSON ----------------------------------------------------------------------
def event_to_json(ev: Event) -> dict[str, Any]:
    if isinstance(ev, Parva):
        return {"type": "parva", "offset": ev.offset, "seq": ev.seq, "n": ev.n, "k": ev.k,
                "id": ev.id, "d": ev.d, "delta": ev.delta}  # fmt: skip
    if isinstance(ev, Parvh):
        return {"type": "parvh", "offset": ev.offset, "seq": ev.seq, "k": ev.k, "id": ev.id, "h": list(ev.h)}
    if isinstance(ev, DecodeError):
        return {"type": "error", "kind": ev.kind.name, "offset": ev.offset, "length": ev.length}
    return {"type": "epoch", **ev.to_json(), "n": ev.n, "gap": ev.gap}


def event_from_json(d: dict[str, Any]) -> Event:
    t = d["type"]
    if t == "parva":
        return Parva(d["offset"], d["seq"], d["n"], d["k"], d["id"], d["d"], d["delta"])
    if t == "parvh":
        return Parvh(d["offset"], d["seq"], d["k"], d["id"], tuple(float(x) for x in d["h"]))  # type: ignore[arg-type]
    if t == "error":
        return DecodeError(ErrorKind[d["kind"]], d["offset"], d["length"])
    if t == "epoch":
        field = d.get("field")
        slots = tuple(None if s is None else tuple(s) for s in d["slots"])
        fields = None if field is None else tuple(None if f is None else tuple(map(float, f)) for f in field)
        return Epoch(d["seq"], d["n"], d["complete"], slots, fields, d["gap"])
    raise ValueError(f"unknown event type {t!r}")


# -- canonical text (identical to firmware_proto/c/test_support.c) ------------------------
def _g(x: float) -> str:
    return "%.17g" % x


def event_text(ev: Event) -> str:
    if isinstance(ev, Parva):
        return f"parva {ev.offset} {ev.seq} {ev.n} {ev.k} {ev.id} {ev.d} {ev.delta}"
    if isinstance(ev, Parvh):
        return f"parvh {ev.offset} {ev.seq} {ev.k} {ev.id} {_g(ev.h[0])} {_g(ev.h[1])} {_g(ev.h[2])}"
    if isinstance(ev, DecodeError):
        return f"error {ev.kind.name} {ev.offset} {ev.length}"
    slots = ";".join("-" if s is None else f"{s[0]},{s[1]},{s[2]}" for s in ev.slots)
    text = f"epoch {ev.seq} {ev.n} {int(ev.complete)} {ev.gap} {slots}"
    if ev.fields is not None:
        text += " " + ";".join("-" if f is None else ",".join(_g(x) for x in f) for f in ev.fields)
    return text


def stats_text(stats: DecoderStats | dict[str, int]) -> str:
    d = stats.as_dict() if isinstance(stats, DecoderStats) else stats
    return "stats " + " ".join(f"{k}={d[k]}" for k in DecoderStats().as_dict())  # the counters' order


# -- the C table ----------------------------------------------------------------------------
def _c_bytes(data: bytes) -> str:
    """A C string literal holding exactly ``data``: printable ASCII as is, everything else
    as a three-digit octal escape (which can never swallow a following digit); split
    into adjacent literals of about 70 characters, never inside an escape."""
    out, cur = [], ""
    for b in data:
        piece = chr(b) if 0x20 <= b <= 0x7E and b not in (0x22, 0x5C, 0x3F) else "\\%03o" % b
        if len(cur) + len(piece) > 70:
            out.append(cur)
            cur = ""
        cur += piece
    out.append(cur)
    return " ".join(f'"{c}"' for c in out)


def _c_double(x: float) -> str:
    if x != x:
        return "NAN"
    if x in (float("inf"), float("-inf")):
        return "HUGE_VAL" if x > 0 else "(-HUGE_VAL)"
    return repr(float(x))


def c_table() -> str:
    """The C source of ``vectors.inc`` (decode and encode tables) from the JSON files."""
    lines = [
        "/* Generated by `python -m firmware_proto.golden c-table` from firmware_proto/vectors/ (JSON).",
        " * Do not edit; tests/firmware_proto/test_vectors.py checks that it is up to date. */",
        "",
        "static const struct decode_vector DECODE_VECTORS[] = {",
    ]
    for case in load("decode"):
        data = to_bytes(case["input"])
        events = "".join(event_text(event_from_json(e)) + "\n" for e in case["events"])
        lines.append(f"    {{{json.dumps(case['name'])},")
        lines.append(f"     {_c_bytes(data)}, {len(data)}, {int(bool(case.get('expect_fields', False)))},")
        lines.append(f"     {_c_bytes(events.encode())},")
        lines.append(f"     {_c_bytes(stats_text(case['stats']).encode())}}},")
    lines += ["};", ""]
    slot_arrays = []
    enc = []
    for i, case in enumerate(load("encode")):
        kind, args, expect = case["sentence"], case["args"], case["bytes"]
        doubles, slots, nslots = ["0.0"] * 3, "0", 0
        if kind == "parva":
            ints = [str(int(a)) for a in args]
        elif kind == "parvh":
            ints = [str(int(a)) for a in args[:3]] + ["0"] * 3
            doubles = [_c_double(float(a)) for a in args[3:]]
        else:
            ints = [str(int(args[0]))] + ["0"] * 5
            nslots = len(args[1])
            if nslots:
                slots = f"ENC_SLOTS_{i}"
                body = ", ".join(f"{{{a}, {b}, {c}}}" for a, b, c in args[1])
                slot_arrays.append(f"static const arva_slot {slots}[] = {{{body}}};")
        valid = expect is not None
        exp = to_bytes(expect) if valid else b""
        enc.append(
            f"    {{{json.dumps(case['name'])}, ENC_{kind.upper()}, {{{', '.join(ints)}}}, "
            f"{{{', '.join(doubles)}}}, {slots}, {nslots}, {int(valid)}, {_c_bytes(exp)}, {len(exp)}}},"
        )
    lines += slot_arrays
    lines += ["", "static const struct encode_vector ENCODE_VECTORS[] = {"] + enc + ["};", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) == 2 and argv[0] == "c-table":
        Path(argv[1]).write_text(c_table())
        return 0
    print("usage: python -m firmware_proto.golden c-table OUT.inc", file=sys.stderr)
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
