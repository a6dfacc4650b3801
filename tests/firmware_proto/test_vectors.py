"""Golden vectors (firmware_proto/vectors/*.json) against both implementations."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from c_codec import C_DIR, STRICT, build_dir, build_runner, compile_c, find_cc
from firmware_proto.decoder import Decoder
from firmware_proto.errors import ProtocolError
from firmware_proto.events import ErrorKind
from firmware_proto.golden import C_TABLE, c_table, event_to_json, from_bytes, load, to_bytes
from firmware_proto.sentences import encode_epoch, encode_parva, encode_parvh

DECODE = load("decode")
ENCODE = load("encode")
needs_cc = pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc) on PATH; the C codec cannot be built")


def _decode(data: bytes, chunks: list[int], expect_fields: bool) -> tuple[list[dict], dict]:
    dec = Decoder(expect_fields=expect_fields)
    events = []
    pos = 0
    for size in chunks:
        events += dec.feed(data[pos : pos + size])
        pos += size
    events += dec.feed(data[pos:])
    events += dec.flush()
    return [event_to_json(e) for e in events], dec.stats.as_dict()


def test_vector_files_are_well_formed() -> None:
    names = [c["name"] for c in DECODE]
    assert len(names) == len(set(names)) and len(DECODE) >= 100
    assert len({c["name"] for c in ENCODE}) == len(ENCODE)
    kinds = {e["kind"] for c in DECODE for e in c["events"] if e["type"] == "error"}
    assert kinds == {k.name for k in ErrorKind}, "every error kind has a golden vector"
    for c in DECODE:  # every byte accounted for: good sentences + rejected + garbage
        data = to_bytes(c["input"])
        good = 0
        for e in c["events"]:
            if e["type"] in ("parva", "parvh"):
                good += data.index(b"\n", e["offset"]) + 1 - e["offset"]
        bad = sum(e["length"] for e in c["events"] if e["type"] == "error")
        assert good + bad + c["stats"]["garbage_bytes"] == len(data) == c["stats"]["bytes"], c["name"]


@pytest.mark.parametrize("case", DECODE, ids=[c["name"] for c in DECODE])
def test_python_decoder_matches_vector(case: dict) -> None:
    data = to_bytes(case["input"])
    ef = case.get("expect_fields", False)
    events, stats = _decode(data, [], ef)
    assert events == case["events"]
    assert stats == case["stats"]
    # The result must not depend on how the stream is split.
    assert _decode(data, [1] * len(data), ef) == (case["events"], case["stats"])
    for cut in range(1, len(data)):
        assert _decode(data, [cut], ef) == (case["events"], case["stats"]), f"cut at {cut}"


def _py_encode(case: dict) -> bytes | None:
    a = case["args"]
    try:
        if case["sentence"] == "parva":
            return encode_parva(*a)
        if case["sentence"] == "parvh":
            return encode_parvh(a[0], a[1], a[2], [float(x) for x in a[3:]])
        return encode_epoch(a[0], [tuple(s) for s in a[1]])
    except ProtocolError:
        return None


@pytest.mark.parametrize("case", ENCODE, ids=[c["name"] for c in ENCODE])
def test_python_encoder_matches_vector(case: dict) -> None:
    out = _py_encode(case)
    assert (None if out is None else from_bytes(out)) == case["bytes"]


def test_encoded_vectors_decode_to_their_arguments() -> None:
    for case in ENCODE:
        if case["bytes"] is None or case["sentence"] != "parva":
            continue
        dec = Decoder()
        (p, *_rest) = dec.feed(to_bytes(case["bytes"]))
        assert [p.seq, p.n, p.k, p.id, p.d, p.delta] == case["args"]


def test_c_table_is_up_to_date() -> None:
    assert C_TABLE.read_text() == c_table(), "run: python -m firmware_proto.golden c-table firmware_proto/c/vectors.inc"


@pytest.mark.subprocess
@needs_cc
@pytest.mark.timeout(300)
def test_c_runner_passes_every_vector() -> None:
    exe = build_runner()
    proc = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip() == f"{len(DECODE)} decode + {len(ENCODE)} encode vectors, 0 failed"


@pytest.mark.subprocess
@needs_cc
@pytest.mark.timeout(300)
def test_c_runner_fails_on_a_wrong_vector() -> None:
    """The runner is not vacuous: one changed expectation makes it exit 1 naming the case."""
    d = build_dir() / "mutant"
    d.mkdir(exist_ok=True)
    for f in ("arva_codec.c", "arva_codec.h", "test_support.c", "test_support.h", "test_vectors.c"):
        shutil.copy(C_DIR / f, d / f)
    table = C_TABLE.read_text()
    assert "epoch 0 1 1 0 1,1905,21" in table
    (d / "vectors.inc").write_text(table.replace("epoch 0 1 1 0 1,1905,21", "epoch 0 1 1 0 1,1905,22", 1))
    exe = d / "runner"
    compile_c([*STRICT, str(d / "arva_codec.c"), str(d / "test_support.c"), str(d / "test_vectors.c"), "-lm", "-o", str(exe)])
    proc = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "FAIL brief-example-slot (one chunk): events differ" in proc.stdout
    assert proc.stdout.strip().endswith("1 failed")
