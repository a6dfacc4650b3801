"""Hypothesis strategies: valid epochs interleaved with line noise, truncations, flipped
bits, dropped sentences, over-long lines, binary bursts and foreign sentences.

The damage is built so that the ground truth stays knowable:

* an epoch is *intact* when none of its sentences was touched and nothing was inserted
  between them; a correct decoder must report every intact epoch, complete, exactly once,
  in stream order;
* at most one modification per sentence (one bit flip, or one truncation, or a drop, or
  noise after it). A single flipped bit is always caught by the XOR checksum or by the
  framing, so no damaged sentence can decode to different data;
* free noise never contains LF, ``*`` or ``PARV``: a truncated sentence followed by noise
  can then only be closed by a later LF with no new ``*``, so it can never turn into a
  valid sentence carrying other data than the original. (Noise lines end in CR LF but
  have no ``*`` either.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hypothesis import strategies as st

from firmware_proto.sentences import MAX_ABS_DELTA, MAX_D_CM, MAX_ID, encode_parva, encode_parvh, frame

EMPTY = (-1, -1, -1)


@dataclass(frozen=True)
class EpochSpec:
    seq: int
    slots: tuple[tuple[int, int, int], ...]
    fields: tuple[tuple[float, float, float] | None, ...] | None  # None: no $PARVH at all

    def sentences(self) -> list[bytes]:
        out = []
        n = len(self.slots)
        for k, slot in enumerate(self.slots, start=1):
            out.append(encode_parva(self.seq, n, k, *slot))
            if self.fields is not None and self.fields[k - 1] is not None:
                out.append(encode_parvh(self.seq, k, slot[0], self.fields[k - 1]))
        return out

    def decoded_fields(self) -> tuple[tuple[float, float, float] | None, ...] | None:
        """The fields as a decoder sees them (after %.6e)."""
        if self.fields is None or all(f is None for f in self.fields):
            return None
        return tuple(None if f is None else tuple(float("%.6e" % x) for x in f) for f in self.fields)  # type: ignore[misc]


@dataclass(frozen=True)
class Stream:
    data: bytes
    epochs: tuple[EpochSpec, ...]  # in stream order
    intact: tuple[bool, ...]
    expect_fields: bool


slots = st.one_of(
    st.just(EMPTY),
    st.tuples(
        st.integers(0, MAX_ID),
        st.one_of(st.integers(0, 6000), st.integers(0, MAX_D_CM)),
        st.integers(-MAX_ABS_DELTA, MAX_ABS_DELTA),
    ),
)
components = st.floats(allow_nan=False, allow_infinity=False, width=64).filter(lambda x: math.isfinite(float("%.6e" % x)))
fields = st.tuples(components, components, components)

_PRINTABLE = bytes(range(0x20, 0x7F))
_NOISE_LINE_ALPHABET = _PRINTABLE.replace(b"*", b"").replace(b"$", b"")


def _clean(b: bytes) -> bytes:
    b = b.replace(b"\n", b"").replace(b"*", b"")
    while b"PARV" in b:
        b = b.replace(b"PARV", b"PRV")
    return b


noise = st.one_of(
    st.binary(min_size=1, max_size=40).map(_clean),  # line noise (may hold '$')
    st.binary(min_size=1, max_size=30).map(lambda b: bytes(x | 0x80 for x in b)),  # binary burst
    st.lists(st.sampled_from(_NOISE_LINE_ALPHABET), max_size=30).map(lambda xs: bytes(xs) + b"\r\n"),  # junk line
    st.tuples(st.integers(82, 160), st.sampled_from(_NOISE_LINE_ALPHABET)).map(  # over-long line
        lambda t: b"$" + bytes([t[1]]) * t[0] + b"\r\n"
    ),
    st.sampled_from([frame("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"), frame("PASHR,1,2,3")]),
)


def _modify(draw, sentence: bytes) -> tuple[bytes, bool]:  # type: ignore[no-untyped-def]
    """One modification, or none; returns (bytes, untouched)."""
    what = draw(st.sampled_from(["keep", "keep", "keep", "drop", "truncate", "flip", "noise"]))
    if what == "keep":
        return sentence, True
    if what == "drop":
        return b"", False
    if what == "truncate":
        return sentence[: draw(st.integers(1, len(sentence) - 1))], False
    if what == "flip":
        pos = draw(st.integers(0, len(sentence) - 1))
        bit = draw(st.integers(0, 7))
        b = bytearray(sentence)
        b[pos] ^= 1 << bit
        return bytes(b), False
    return sentence + draw(noise), False


@st.composite
def hostile_streams(draw, max_epochs: int = 8, damage: bool = True, with_noise: bool = True):  # type: ignore[no-untyped-def]
    with_fields = draw(st.booleans())
    expect_fields = draw(st.booleans()) if with_fields else False
    seq = draw(st.integers(0, 65535))
    n_epochs = draw(st.integers(0, max_epochs))
    parts: list[bytes] = []
    epochs = []
    intact = []
    for i in range(n_epochs):
        if with_noise and draw(st.integers(0, 2)) == 0:
            parts.append(draw(noise))
        if i:
            seq = (seq + 1 + draw(st.sampled_from([0, 0, 0, 1, 2, 7]))) % 65536
        n = draw(st.integers(1, 4))
        s = tuple(draw(st.lists(slots, min_size=n, max_size=n)))
        f = tuple(None if slot == EMPTY else draw(fields) for slot in s) if with_fields else None
        spec = EpochSpec(seq, s, f)
        ok = True
        if damage and draw(st.integers(0, 3)) == 0:
            for sentence in spec.sentences():
                out, untouched = _modify(draw, sentence)
                parts.append(out)
                ok = ok and untouched
        else:
            parts.extend(spec.sentences())
        epochs.append(spec)
        intact.append(ok)
    if with_noise and draw(st.booleans()):
        parts.append(draw(noise))
    return Stream(b"".join(parts), tuple(epochs), tuple(intact), expect_fields)


def chunkings(data: bytes):  # type: ignore[no-untyped-def]
    """Strategy: a list of cut positions splitting ``data`` into feed() chunks."""
    return st.lists(st.integers(0, len(data)), max_size=8).map(sorted)


def split(data: bytes, cuts: list[int]) -> list[bytes]:
    bounds = [0, *cuts, len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:])]
