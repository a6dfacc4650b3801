"""Encoding of the receiver sentences ``$PARVA`` and ``$PARVH`` (BRIEF section 4).

NMEA 0183 framing: ``$`` + body + ``*`` + two upper-case hex digits (XOR of every body
byte) + CR LF, 82 bytes at most in all. Integer fields are plain decimal (``-1`` allowed,
no ``+``, no leading zeros), which is exactly what ``str(int)`` produces.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import reduce
from operator import xor

from .errors import ProtocolError

MAX_SENTENCE = 82  #: bytes, including ``$`` and CR LF (NMEA 0183)
SEQ_MODULO = 65536  #: ``seq`` is the epoch counter modulo this

# Field limits shared by encoder and decoders (Python and C). A slot is either empty,
# (id, d, delta) = (-1, -1, -1), or a transmitter with id >= 0, d >= 0 cm and
# |delta| <= 89 degrees (the receiver folds and clamps delta, BRIEF 3 step 5).
MAX_CHANNELS = 99
MAX_ID = 65535
MAX_D_CM = 9_999_999
MAX_ABS_DELTA = 89

EMPTY_SLOT = (-1, -1, -1)


def checksum(body: bytes) -> int:
    """XOR of all bytes of ``body`` (the text between ``$`` and ``*``)."""
    return reduce(xor, body, 0)


def frame(body: str) -> bytes:
    """Wrap an ASCII sentence body as ``$body*HH\\r\\n``; raise if over 82 bytes."""
    raw = body.encode("ascii")
    out = b"$%s*%02X\r\n" % (raw, reduce(xor, raw, 0))
    if len(out) > MAX_SENTENCE:
        raise ProtocolError(f"sentence of {len(out)} bytes exceeds {MAX_SENTENCE}: {body!r}")
    return out


def check_slot(tx_id: int, d: int, delta: int) -> None:
    """Raise :class:`ProtocolError` unless (id, d, delta) is a slot the protocol can carry."""
    if (tx_id, d, delta) == EMPTY_SLOT:
        return
    if not 0 <= tx_id <= MAX_ID:
        raise ProtocolError(f"id {tx_id} outside 0..{MAX_ID}")
    if not 0 <= d <= MAX_D_CM:
        raise ProtocolError(f"d {d} outside 0..{MAX_D_CM} cm")
    if not -MAX_ABS_DELTA <= delta <= MAX_ABS_DELTA:
        raise ProtocolError(f"delta {delta} outside -{MAX_ABS_DELTA}..{MAX_ABS_DELTA} deg")


def encode_parva(seq: int, n: int, k: int, tx_id: int, d: int, delta: int) -> bytes:
    """One ``$PARVA`` sentence: slot ``k`` (1-based) of ``n`` in epoch ``seq``."""
    if not 0 <= seq < SEQ_MODULO:
        raise ProtocolError(f"seq {seq} outside 0..{SEQ_MODULO - 1}")
    if not 1 <= n <= MAX_CHANNELS:
        raise ProtocolError(f"n {n} outside 1..{MAX_CHANNELS}")
    if not 1 <= k <= n:
        raise ProtocolError(f"k {k} outside 1..{n}")
    check_slot(tx_id, d, delta)
    return frame(f"PARVA,{seq},{n},{k},{tx_id},{d},{delta}")


def format_field(value: float) -> str:
    """One ``$PARVH`` field component, ``%.6e``; a non-finite value is an error."""
    if value != value or value in (float("inf"), float("-inf")):
        raise ProtocolError(f"field component {value!r} is not finite")
    return "%.6e" % value


def encode_parvh(seq: int, k: int, tx_id: int, h: Sequence[float]) -> bytes:
    """One ``$PARVH`` research sentence: receiver-frame field of slot ``k``, scene units."""
    if not 0 <= seq < SEQ_MODULO:
        raise ProtocolError(f"seq {seq} outside 0..{SEQ_MODULO - 1}")
    if not 1 <= k <= MAX_CHANNELS:
        raise ProtocolError(f"k {k} outside 1..{MAX_CHANNELS}")
    if not (tx_id == -1 or 0 <= tx_id <= MAX_ID):
        raise ProtocolError(f"id {tx_id} outside 0..{MAX_ID}")
    hx, hy, hz = (format_field(float(v)) for v in h)
    return frame(f"PARVH,{seq},{k},{tx_id},{hx},{hy},{hz}")


def encode_epoch(
    seq: int,
    slots: Sequence[tuple[int, int, int]],
    fields: Sequence[Sequence[float] | None] | None = None,
) -> bytes:
    """All sentences of one epoch: a ``$PARVA`` per slot, each followed by its
    ``$PARVH`` when ``fields`` is given (``None`` entries, e.g. empty slots, get none)."""
    seq %= SEQ_MODULO
    n = len(slots)
    parts = []
    for k, (tx_id, d, delta) in enumerate(slots, start=1):
        parts.append(encode_parva(seq, n, k, tx_id, d, delta))
        if fields is not None and fields[k - 1] is not None:
            parts.append(encode_parvh(seq, k, tx_id, fields[k - 1]))
    return b"".join(parts)
