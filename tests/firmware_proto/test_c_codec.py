"""The C codec (ctypes) must agree with the Python one on every stream, event for event."""

from __future__ import annotations

import platform
import shutil
import subprocess
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from c_codec import C_DIR, SANITIZE, STRICT, CDecoder, c_encode_epoch, c_encode_parvh, compile_c, find_cc, sanitizers_work
from firmware_proto.decoder import Decoder
from firmware_proto.errors import ProtocolError
from firmware_proto.golden import event_text, stats_text
from firmware_proto.sentences import encode_epoch, encode_parvh, format_field, frame
from hostile_streams import EMPTY, Stream, fields, hostile_streams, slots, split

pytestmark = pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc) on PATH; the C codec cannot be built")


def both(chunks: list[bytes], expect_fields: bool, idle_after: set[int] = frozenset()) -> tuple:  # type: ignore[assignment]
    py, c = Decoder(expect_fields), CDecoder(expect_fields)
    py_lines: list[str] = []
    c_lines: list[str] = []
    for i, chunk in enumerate(chunks):
        py_lines += [event_text(e) for e in py.feed(chunk)]
        c_lines += c.feed(chunk)
        if i in idle_after:
            py_lines += [event_text(e) for e in py.idle()]
            c_lines += c.idle()
    py_lines += [event_text(e) for e in py.flush()]
    c_lines += c.flush()
    return py_lines, c_lines, stats_text(py.stats), c.stats()


def assert_agree(chunks: list[bytes], expect_fields: bool = False, idle_after: set[int] = frozenset()) -> None:  # type: ignore[assignment]
    py_lines, c_lines, py_stats, c_stats = both(chunks, expect_fields, idle_after)
    assert c_lines == py_lines
    assert c_stats == py_stats


@pytest.mark.subprocess
@given(hostile_streams(), st.data())
def test_c_agrees_on_hostile_streams(stream: Stream, data: st.DataObject) -> None:
    cuts = data.draw(st.lists(st.integers(0, len(stream.data)), max_size=6).map(sorted))
    chunks = split(stream.data, cuts)
    idle_after = set(data.draw(st.lists(st.integers(0, len(chunks) - 1), max_size=3)))
    assert_agree(chunks, stream.expect_fields, idle_after)


# Near-valid lines: correct checksums over bodies with wrong ids, counts, signs, zeros,
# huge numbers and odd floats, so that every MALFORMED / OUT_OF_RANGE rule is exercised.
_int_tokens = st.one_of(
    st.integers(-100, 100).map(str),
    st.integers(-(10**12), 10**12).map(str),
    st.sampled_from(["", "-", "-0", "00", "01", "+1", "1.0", " 1", "1a", "65535", "65536", "99", "100", "89", "-89",
                     "90", "-90", "9999999", "10000000", "999999999", "1000000000", "-1"]),
)  # fmt: skip
_float_tokens = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(lambda x: "%.6e" % x),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.from_regex(r"-?[0-9]{1,3}(\.[0-9]{1,3})?([eE][+-]?[0-9]{1,4})?", fullmatch=True),
    st.from_regex(r"-?[0-9]{1,3}(\.[0-9]{0,20})?e\+?3[01][0-9]", fullmatch=True),  # near the overflow limit
    st.sampled_from(["inf", "nan", "1.", ".5", "+1", "1e", "1e+", "0x10", "1.7976931348623157e308",
                     "1.7976931348623159e308", "1.797694e+308", "179769313486231580793728971405303415e273",
                     "179769313486231580793728971405303416e273", "0.0000000001e318", "1" + "0" * 31, "1" + "0" * 32]),
)  # fmt: skip
_address = st.sampled_from(["PARVA", "PARVA", "PARVH", "PARVH", "PARVX", "GPGGA", "", "parva", "PARV"])


@st.composite
def near_valid_line(draw) -> bytes:  # type: ignore[no-untyped-def]
    addr = draw(_address)
    count = draw(st.sampled_from([6, 6, 6, 5, 7, 0]))
    if addr == "PARVH":
        toks = [draw(_int_tokens) for _ in range(min(3, count))] + [draw(_float_tokens) for _ in range(max(0, count - 3))]
    else:
        toks = [draw(_int_tokens) for _ in range(count)]
    body = ",".join([addr, *toks]).encode()
    x = 0
    for b in body:
        x ^= b
    cs = b"%02X" % x
    cs = draw(st.sampled_from([cs, cs, cs, cs.lower(), b"%02X" % (x ^ 1), b"G0", cs[:1]]))
    end = draw(st.sampled_from([b"\r\n", b"\r\n", b"\r\n", b"\n", b"", b"\r\r\n"]))
    return b"$" + body + b"*" + cs + end


@given(st.lists(st.one_of(near_valid_line(), st.binary(max_size=12)), max_size=12), st.booleans(), st.data())
def test_c_agrees_on_near_valid_lines(parts: list[bytes], expect_fields: bool, data: st.DataObject) -> None:
    stream = b"".join(parts)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=4).map(sorted))
    assert_agree(split(stream, cuts), expect_fields)


@given(st.binary(max_size=400), st.booleans())
@settings(max_examples=100)
def test_c_agrees_on_random_bytes(stream: bytes, expect_fields: bool) -> None:
    assert_agree([stream], expect_fields)


def test_c_agrees_on_long_streams() -> None:
    """Offsets, gap counters and the epoch buffers over many epochs and a seq wrap."""
    data = b"".join(
        encode_epoch(s % 65536, [(s % 7, s * 3 % 10000, s % 179 - 89), EMPTY, (2, 5, 0)][: 1 + s % 3])
        + (b"\xff$GP*" if s % 11 == 0 else b"")
        for s in range(65000, 66500, 3)
    )
    assert_agree([data[i : i + 4096] for i in range(0, len(data), 4096)])


@given(st.lists(slots, min_size=1, max_size=99), st.integers(0, 2**32 - 1))
@settings(max_examples=100)
def test_c_encoder_matches_python(epoch: list, seq: int) -> None:
    assert c_encode_epoch(seq, epoch) == encode_epoch(seq, epoch)


@given(st.integers(0, 65535), st.integers(1, 99), st.sampled_from([-1, 0, 1, 65535]), fields)
@settings(max_examples=100)
def test_c_parvh_encoder_matches_python(seq: int, k: int, tx_id: int, h: tuple) -> None:
    try:
        expected = encode_parvh(seq, k, tx_id, h)
        text = tuple(format_field(x).encode() for x in h)
    except ProtocolError:
        return
    assert c_encode_parvh(seq, k, tx_id, text) == expected


def test_c_parvh_encoder_refuses_bad_text() -> None:
    ok = (b"1.0", b"-2e-3", b"0")
    assert c_encode_parvh(1, 1, 1, ok) == frame("PARVH,1,1,1,1.0,-2e-3,0")
    for bad in (b"inf", b"nan", b"1.", b"+1", b"1e999", b"", b"1" * 33):
        assert c_encode_parvh(1, 1, 1, (bad, b"0", b"0")) is None, bad
    assert c_encode_parvh(1, 1, 1, (b"1" * 30, b"2" * 30, b"3" * 10)) is None  # 90 bytes > 82


@pytest.mark.subprocess
def test_firmware_example_builds_strict_and_runs(tmp_path: Path) -> None:
    exe = tmp_path / "example"
    flags = STRICT + (SANITIZE if sanitizers_work() else [])
    compile_c([*flags, str(C_DIR / "arva_codec.c"), str(C_DIR / "example.c"), "-o", str(exe)])
    assert subprocess.run([str(exe)], timeout=30).returncode == 0


@pytest.mark.subprocess
@pytest.mark.parametrize("config", [[], ["-DARVA_MAX_CHANNELS=4", "-DARVA_WITH_FIELDS=0"]])
def test_codec_needs_no_floating_point_and_no_library(tmp_path: Path, config: list[str]) -> None:
    """Compiled with the FPU registers forbidden (where the compiler can), and the object
    file calls nothing but what a compiler may emit for loops and struct copies."""
    obj = tmp_path / "arva_codec.o"
    no_fp = ["-mgeneral-regs-only"] if platform.machine() in ("x86_64", "aarch64", "arm64") else []
    try:
        compile_c([*STRICT, *config, *no_fp, "-O2", "-c", str(C_DIR / "arva_codec.c"), "-o", str(obj)])
    except RuntimeError as exc:
        if no_fp and "general-regs-only" in str(exc) and "unrecognized" in str(exc):
            pytest.skip("compiler has no -mgeneral-regs-only")
        raise
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm to list undefined symbols")
    undefined = set(subprocess.run([nm, "-u", str(obj)], capture_output=True, text=True, timeout=30).stdout.split()) - {"U"}
    assert undefined <= {"memcpy", "memset", "memmove", "strlen"}, undefined
