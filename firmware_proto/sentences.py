"""Encoding of the receiver sentences ``$PARVA`` and ``$PARVH`` (BRIEF section 4).

NMEA 0183 framing: ``$`` + body + ``*`` + two upper-case hex digits (XOR of every body
byte) + CR LF, 82 bytes at most in all. Integer fields are plain decimal (``-1`` allowed,
no ``+``, no leading zeros), which is exactly what ``str(int)`` produces.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache, reduce
from operator import xor

import numpy as np

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
    out = b"$%s*%02X\r\n" % (raw, checksum(raw))
    if len(out) > MAX_SENTENCE:
        raise ProtocolError(f"sentence of {len(out)} bytes exceeds {MAX_SENTENCE}: {body!r}")
    return out


def _within(name: str, value: int, lo: int, hi: int, unit: str = "") -> None:
    """:class:`ProtocolError` ``NAME VALUE outside LO..HI[ UNIT]`` unless lo <= value <= hi."""
    if not lo <= value <= hi:
        raise ProtocolError(f"{name} {value} outside {lo}..{hi}{unit}")


def check_slot(tx_id: int, d: int, delta: int) -> None:
    """Raise :class:`ProtocolError` unless (id, d, delta) is a slot the protocol can carry."""
    if (tx_id, d, delta) != EMPTY_SLOT:
        _within("id", tx_id, 0, MAX_ID)
        _within("d", d, 0, MAX_D_CM, " cm")
        _within("delta", delta, -MAX_ABS_DELTA, MAX_ABS_DELTA, " deg")


def encode_parva(seq: int, n: int, k: int, tx_id: int, d: int, delta: int) -> bytes:
    """One ``$PARVA`` sentence: slot ``k`` (1-based) of ``n`` in epoch ``seq``."""
    _within("seq", seq, 0, SEQ_MODULO - 1)
    _within("n", n, 1, MAX_CHANNELS)
    _within("k", k, 1, n)
    check_slot(tx_id, d, delta)
    return frame(f"PARVA,{seq},{n},{k},{tx_id},{d},{delta}")


def format_field(value: float) -> str:
    """One ``$PARVH`` field component, ``%.6e``; a non-finite value is an error."""
    if value != value or value in (float("inf"), float("-inf")):
        raise ProtocolError(f"field component {value!r} is not finite")
    return "%.6e" % value


def encode_parvh(seq: int, k: int, tx_id: int, h: Sequence[float]) -> bytes:
    """One ``$PARVH`` research sentence: receiver-frame field of slot ``k``, scene units."""
    _within("seq", seq, 0, SEQ_MODULO - 1)
    _within("k", k, 1, MAX_CHANNELS)
    if tx_id != -1:
        _within("id", tx_id, 0, MAX_ID)
    hx, hy, hz = (format_field(float(v)) for v in h)
    return frame(f"PARVH,{seq},{k},{tx_id},{hx},{hy},{hz}")


def encode_epoch(seq: int, slots: Sequence[tuple[int, int, int]],
                 fields: Sequence[Sequence[float] | None] | None = None) -> bytes:
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


def _as_lists(x):
    return x.tolist() if hasattr(x, "tolist") else [list(row) for row in x]


def encode_epochs(
    k0: int, ids: Sequence[Sequence[int]], d: Sequence[Sequence[int]], delta: Sequence[Sequence[int]],
    fields: Sequence[Sequence[Sequence[float]]] | None = None,
) -> bytes:
    """Consecutive epochs ``k0, k0 + 1, ...`` at once; rows are epochs, columns slots.

    Accepts nested sequences or numpy arrays (anything with ``tolist``). Fields, when
    given, add a ``$PARVH`` after every non-empty slot. Same bytes as calling
    :func:`encode_epoch` per epoch, but checks values once per batch and reuses the
    slot formatting in one loop, which keeps the emulator's hot path fast.
    """
    if fields is None and all(isinstance(x, np.ndarray) and x.dtype.kind in "iu" for x in (ids, d, delta)):
        fast = _encode_parva_arrays(k0, ids, d, delta)
        if fast is not None:
            return fast
    ids_l, d_l, delta_l = (_as_lists(x) for x in (ids, d, delta))
    n_epochs = len(ids_l)
    if n_epochs == 0:
        return b""
    n = len(ids_l[0])
    _within("n", n, 1, MAX_CHANNELS)
    for row_ids, row_d, row_delta in zip(ids_l, d_l, delta_l):
        for slot in zip(row_ids, row_d, row_delta):
            check_slot(*slot)
    fields_l = None if fields is None else _as_lists(fields)
    out = []
    append = out.append
    for e in range(n_epochs):
        seq = (k0 + e) % SEQ_MODULO
        for k in range(n):
            tx_id = ids_l[e][k]
            body = f"PARVA,{seq},{n},{k + 1},{tx_id},{d_l[e][k]},{delta_l[e][k]}".encode()
            append(b"$%s*%02X\r\n" % (body, reduce(xor, body, 0)))
            if fields_l is not None and tx_id != -1:
                append(encode_parvh(seq, k + 1, tx_id, fields_l[e][k]))
    return b"".join(out)


#: Element-wise concatenation of bytes arrays (np.strings from numpy 2.0, np.char before).
_STRING_ADD = getattr(np, "strings", np.char).add
_HEX_CRLF = np.array([b"%02X\r\n" % i for i in range(256)], dtype="S4")


@cache
def _tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Built on first use, indexed by value + 89 for value in -89 .. 65535: the decimal
    text (str(value)), the same with a leading comma, and the XOR of that text's bytes."""
    text = np.arange(-MAX_ABS_DELTA, 65536).astype("S6")
    xor_of_text = np.bitwise_xor.reduce(text.view(np.uint8).reshape(-1, text.dtype.itemsize), axis=1)
    return text, _STRING_ADD(b",", text), xor_of_text


def _encode_parva_arrays(k0: int, ids: np.ndarray, d: np.ndarray, delta: np.ndarray) -> bytes | None:
    """$PARVA sentences of whole epochs, built column-wise with numpy string ufuncs.

    Same bytes as the per-slot loop of :func:`encode_epochs`. Fields come from tables of
    decimal text; the checksum, a XOR over the body, is the XOR of the fields' own XORs
    (also tabled) and of the constant parts; the fixed-width results are joined by
    dropping their NUL padding (no sentence contains a NUL). Returns None when a value
    is outside the tables or a slot is invalid, so that the loop handles (or rejects) it.
    """
    if ids.ndim != 2 or ids.shape != d.shape or ids.shape != delta.shape:
        return None
    n_epochs, n = ids.shape
    if not 1 <= n <= MAX_CHANNELS:
        return None
    empty = (ids == -1) & (d == -1) & (delta == -1)
    valid = (ids >= 0) & (ids <= MAX_ID) & (d >= 0) & (d <= 65535) & (np.abs(delta) <= MAX_ABS_DELTA)
    if not np.all(empty | valid):
        return None  # includes d beyond 655.35 m: the loop formats those
    text, comma, tx = _tables()
    off = MAX_ABS_DELTA
    seq = (k0 + np.arange(n_epochs, dtype=np.int64)) % SEQ_MODULO + off
    heads = [f",{n},{k}," for k in range(1, n + 1)]
    head = np.array([h.encode() for h in heads], dtype="S8")
    head_x = np.array([checksum(h.encode()) for h in heads], dtype=np.uint8)
    i1, d1, e1 = ids + off, d + off, delta + off
    add = _STRING_ADD
    out = add(add(b"$PARVA,", text[seq])[:, None], head[None, :])
    out = add(add(add(out, text[i1]), comma[d1]), comma[e1])
    # body = PARVA, seq head id ,d ,delta : its XOR from the parts (',' xor ',' cancels).
    check = tx[seq][:, None] ^ head_x[None, :] ^ tx[i1] ^ tx[d1] ^ tx[e1] ^ np.uint8(checksum(b"PARVA,"))
    out = add(add(out, b"*"), _HEX_CRLF[check])
    raw = np.frombuffer(np.ascontiguousarray(out).tobytes(), dtype=np.uint8)
    return raw[raw != 0].tobytes()
