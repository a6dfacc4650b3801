"""Streaming, hostile-stream-tolerant decoder of ``$PARVA`` / ``$PARVH`` (BRIEF section 4).

Usage: ``Decoder().feed(chunk)`` for each chunk, then ``flush()`` at the end of the
stream; each returns the events it completes (docs/protocol.md section 4).

Framing is a byte-level machine, the same in the C codec: outside a sentence every byte
but ``$`` is garbage (counted); ``$`` starts a sentence (an open one is ``TRUNCATED``), LF
ends it and it is parsed (:func:`parse_line`); a non-printable byte other than CR
(``NON_ASCII``) or an 82nd byte that is not LF (``TOO_LONG``) rejects it, so at most 81
bytes are buffered. The rules and the error order: docs/protocol.md section 2.

The result of feeding a stream does not depend on how it is split into chunks.
"""

from __future__ import annotations

import re
from functools import reduce
from math import isfinite
from operator import xor

from .epochs import EpochAssembler
from .events import DecodeError, DecoderStats, ErrorKind, Event, Parva, Parvh
from .sentences import MAX_ABS_DELTA, MAX_CHANNELS, MAX_D_CM, MAX_ID, MAX_SENTENCE, SEQ_MODULO

#: Longest accepted text of one ``$PARVH`` field component (``%.17e`` needs 25).
MAX_FIELD_TEXT = 32

_INT = re.compile(rb"0|-?[1-9][0-9]*")
_FLOAT = re.compile(rb"-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")
_HEX2 = re.compile(rb"[0-9A-F]{2}")
# Bytes that end an open sentence early: '$', or anything not printable except CR.
_SPECIAL = re.compile(rb"[^\x20-\x23\x25-\x7e\r]")
# The common case, validated in one regex call; anything else takes the exact slow path.
_FAST_PARVA = re.compile(
    rb"\$PARVA,(0|[1-9][0-9]{0,4}),([1-9][0-9]?),([1-9][0-9]?),(-1|0|[1-9][0-9]{0,4}),"
    rb"(-1|0|[1-9][0-9]{0,6}),(0|-?[1-9][0-9]?)\*([0-9A-F]{2})\r"
)
_PX_MIN = 512  # buffers at least this long get a vectorised prefix-XOR table

_SMALL = {str(i).encode(): i for i in range(-99, 100)}  # n, k, delta: dict beats int()
_HEX = {b"%02X" % i: i for i in range(256)}


def _fast_constructor(cls: type, names: tuple[str, ...]):  # type: ignore[no-untyped-def]
    """A positional constructor for a frozen slots dataclass that skips the frozen
    ``__setattr__`` dance (about 30 % faster; the decoder makes one per sentence)."""
    setters = [cls.__dict__[name].__set__ for name in names]
    new = object.__new__
    s0, s1, s2, s3, s4, s5, s6 = setters

    def make(a, b, c, d, e, f, g):  # type: ignore[no-untyped-def]
        obj = new(cls)
        s0(obj, a)
        s1(obj, b)
        s2(obj, c)
        s3(obj, d)
        s4(obj, e)
        s5(obj, f)
        s6(obj, g)
        return obj

    return make


_new_parva = _fast_constructor(Parva, ("offset", "seq", "n", "k", "id", "d", "delta"))


def parse_line(line: bytes, offset: int = 0, max_d_cm: int = MAX_D_CM) -> Parva | Parvh | ErrorKind:
    """Parse one complete line ``$...\\r\\n`` as delimited by the framing machine.

    The caller guarantees what framing guarantees: ``line`` starts with ``$``, ends with
    LF, is at most 82 bytes, and every other byte is printable ASCII (not ``$``) or CR.
    Checks in the order of docs/protocol.md section 2, the first failure naming the kind;
    ``d`` above ``max_d_cm`` (the receiver's range, when the caller knows it) is OUT_OF_RANGE.
    """
    if len(line) < 6 or line[-2] != 13 or line[-5] != 42:
        return ErrorKind.MALFORMED
    hh = line[-4:-2]
    if _HEX2.fullmatch(hh) is None:
        return ErrorKind.MALFORMED
    body = line[1:-5]
    if reduce(xor, body, 0) != int(hh, 16):
        return ErrorKind.BAD_CHECKSUM
    parts = body.split(b",")
    addr = parts[0]
    if addr not in (b"PARVA", b"PARVH"):
        return ErrorKind.UNKNOWN_SENTENCE
    if len(parts) != 7:
        return ErrorKind.MALFORMED
    if addr == b"PARVA":
        if not all(_INT.fullmatch(p) for p in parts[1:]):
            return ErrorKind.MALFORMED
        seq, n, k, tx_id, d, delta = map(int, parts[1:])
        slot_ok = (tx_id == -1 and d == -1 and delta == -1) or (
            0 <= tx_id <= MAX_ID and 0 <= d <= max_d_cm and -MAX_ABS_DELTA <= delta <= MAX_ABS_DELTA)
        if not (0 <= seq < SEQ_MODULO and 1 <= n <= MAX_CHANNELS and 1 <= k <= n and slot_ok):
            return ErrorKind.OUT_OF_RANGE
        return Parva(offset, seq, n, k, tx_id, d, delta)
    if not all(_INT.fullmatch(p) for p in parts[1:4]):
        return ErrorKind.MALFORMED
    if not all(len(p) <= MAX_FIELD_TEXT and _FLOAT.fullmatch(p) for p in parts[4:]):
        return ErrorKind.MALFORMED
    seq, k, tx_id = map(int, parts[1:4])
    h = (float(parts[4]), float(parts[5]), float(parts[6]))
    in_range = 0 <= seq < SEQ_MODULO and 1 <= k <= MAX_CHANNELS and (tx_id == -1 or 0 <= tx_id <= MAX_ID)
    if not (in_range and all(map(isfinite, h))):
        return ErrorKind.OUT_OF_RANGE
    return Parvh(offset, seq, k, tx_id, h)


class Decoder:
    """Bytes in, events out: :class:`Parva`, :class:`Parvh`, :class:`DecodeError`, :class:`Epoch`.

    ``stats`` (:class:`DecoderStats`) counts everything. ``expect_fields=True`` holds every
    epoch for a possible ``$PARVH`` of its last slot from the start (by default that starts
    with the first ``$PARVH`` seen; see :mod:`firmware_proto.epochs`).

    ``max_d_cm`` is a plausibility check on top of the XOR checksum: a ``$PARVA`` whose
    ``d`` exceeds it is rejected as OUT_OF_RANGE. Give the receiver's maximum range (e.g.
    5000 for r_outer = 50 m); the default, the protocol's 9,999,999 cm, adds no check.
    See docs/protocol.md, "What the checksum misses".
    """

    def __init__(self, expect_fields: bool = False, max_d_cm: int = MAX_D_CM) -> None:
        if not (isinstance(max_d_cm, int) and 0 <= max_d_cm <= MAX_D_CM):
            raise ValueError(f"max_d_cm must be an integer in 0..{MAX_D_CM}, got {max_d_cm!r}")
        self.max_d_cm = max_d_cm
        self.stats = DecoderStats()
        self.assembler = EpochAssembler(self.stats, expect_fields=expect_fields)
        self._partial = b""  # open sentence (starts with '$', at most 81 bytes)
        self._partial_offset = 0
        self.offset = 0  #: number of bytes fed so far (the stream offset of the next one)

    def feed(self, data: bytes) -> list[Event]:
        """Decode the next chunk of the stream; return the events it completes, in order."""
        out: list[Event] = []
        if not data:
            return out
        data = bytes(data)
        self.stats.bytes += len(data)
        if self._partial:
            buf = self._partial + data
            base = self._partial_offset
            self._partial = b""
        else:
            buf = data
            base = self.offset
        self.offset += len(data)

        pieces = buf.split(b"\n")
        tail = pieces.pop()
        px = _prefix_xor(buf) if len(buf) >= _PX_MIN else None
        fast = _FAST_PARVA.fullmatch
        max_d = self.max_d_cm
        asm = self.assembler
        stats = self.stats
        on_parva = asm.on_parva
        pos = 0  # of the current piece within buf
        for piece in pieces:
            n = len(piece)
            m = fast(piece) if n < MAX_SENTENCE else None
            if m is not None:
                seq, nn, k, tx_id, d, delta, hh = m.groups()
                cs = px[pos + n - 5] ^ px[pos] if px is not None else reduce(xor, piece[1:-4], 0)
                seq, tx_id, d = int(seq), int(tx_id), int(d)
                nn, k, delta = _SMALL[nn], _SMALL[k], _SMALL[delta]
                if cs == _HEX[hh] and seq < SEQ_MODULO and nn <= MAX_CHANNELS and k <= nn and (
                    (0 <= tx_id <= MAX_ID and 0 <= d <= max_d and -MAX_ABS_DELTA <= delta <= MAX_ABS_DELTA)
                    or (tx_id == -1 and d == -1 and delta == -1)
                ):
                    stats.sentences_ok += 1
                    on_parva(_new_parva(base + pos, seq, nn, k, tx_id, d, delta), out)
                    pos += n + 1
                    continue
            self._scan(piece, base + pos, True, out)
            pos += n + 1
        self._scan(tail, base + pos, False, out)
        return out

    def idle(self) -> list[Event]:
        """Call when the source has been quiet for a while (e.g. a read timed out): releases
        an epoch held for the ``$PARVH`` of its last slot. Never needed on files."""
        out: list[Event] = []
        self.assembler.idle(out)
        return out

    def discard_partial(self) -> int:
        """Forget an unterminated sentence at the end of the input so far, without an error
        (the reader stopped in the middle of it: the stream itself is fine); its length."""
        n = len(self._partial)
        self._partial = b""
        return n

    def flush(self) -> list[Event]:
        """End of stream: an open sentence is TRUNCATED, the pending epoch is emitted.
        The decoder stays usable (offsets and seq tracking continue)."""
        out: list[Event] = []
        if self._partial:
            self._error(ErrorKind.TRUNCATED, self._partial_offset, len(self._partial), out)
            self._partial = b""
        self.assembler.flush(out)
        return out

    # -- slow path: exact per-byte semantics, using find/regex search -------------------
    def _error(self, kind: ErrorKind, offset: int, length: int, out: list[Event]) -> None:
        self.stats.errors[kind] += 1
        self.assembler.on_error(DecodeError(kind, offset, length), out)

    def _scan(self, s: bytes, base: int, terminated: bool, out: list[Event]) -> None:
        """Decode ``s`` (no LF inside), starting outside a sentence; ``terminated``: an LF
        follows ``s`` in the stream (else ``s`` ends the data fed so far)."""
        stats = self.stats
        size = len(s)
        pos = 0
        while True:
            d = s.find(b"$", pos)
            if d < 0:
                stats.garbage_bytes += size - pos + (1 if terminated else 0)
                return
            stats.garbage_bytes += d - pos
            end = min(size, d + MAX_SENTENCE - 1)
            m = _SPECIAL.search(s, d + 1, end)
            if m is not None:
                i = m.start()
                if s[i] == 0x24:
                    self._error(ErrorKind.TRUNCATED, base + d, i - d, out)
                    pos = i
                else:
                    self._error(ErrorKind.NON_ASCII, base + d, i - d + 1, out)
                    pos = i + 1
                continue
            if end < size:  # s[end] is the sentence's 82nd byte, and it is not LF
                c = s[end]
                if c == 0x24:
                    self._error(ErrorKind.TRUNCATED, base + d, end - d, out)
                    pos = end
                elif c == 13 or 0x20 <= c <= 0x7E:
                    self._error(ErrorKind.TOO_LONG, base + d, MAX_SENTENCE, out)
                    pos = end + 1
                else:
                    self._error(ErrorKind.NON_ASCII, base + d, MAX_SENTENCE, out)
                    pos = end + 1
                continue
            if not terminated:
                self._partial = s[d:]
                self._partial_offset = base + d
                return
            line = s[d:] + b"\n"
            result = parse_line(line, base + d, self.max_d_cm)
            if isinstance(result, ErrorKind):
                self._error(result, base + d, len(line), out)
            else:
                stats.sentences_ok += 1
                if type(result) is Parva:
                    self.assembler.on_parva(result, out)
                else:
                    self.assembler.on_parvh(result, out)
            return


def _prefix_xor(buf: bytes) -> bytes:
    """``px[i]`` = XOR of ``buf[0..i]``; the XOR of ``buf[a+1..b]`` is ``px[b] ^ px[a]``."""
    import numpy as np

    return np.bitwise_xor.accumulate(np.frombuffer(buf, dtype=np.uint8)).tobytes()


def decode(data: bytes, expect_fields: bool = False, max_d_cm: int = MAX_D_CM) -> tuple[list[Event], DecoderStats]:
    """Decode a whole stream at once (feed + flush)."""
    dec = Decoder(expect_fields=expect_fields, max_d_cm=max_d_cm)
    events = dec.feed(data)
    events += dec.flush()
    return events, dec.stats
