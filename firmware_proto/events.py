"""What the streaming decoder reports: sentences, errors, epochs, and its counters.

Every event is an immutable (frozen) dataclass. ``offset`` is the position in the byte
stream (0 = first byte ever fed) of the ``$`` that started the sentence; ``length`` of a
:class:`DecodeError` is the number of bytes the rejected sentence consumed, so every byte
of a stream is accounted for exactly once: part of a good sentence, part of a rejected
one, or a garbage byte (outside any sentence, counted in :class:`DecoderStats`).

The :class:`ErrorKind` numbers are the same in the C codec (``arva_error_kind``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, fields

Slot = tuple[int, int, int]
Field = tuple[float, float, float]


class ErrorKind(enum.IntEnum):
    """Why a sentence was rejected. Same names and numbers as ``ARVA_<NAME>`` in C."""

    BAD_CHECKSUM = 1  #: well-formed frame, but the XOR of the body differs from ``*hh``
    TOO_LONG = 2  #: 82 bytes without the closing LF (reported at the 82nd byte)
    NON_ASCII = 3  #: a byte outside printable ASCII 0x20-0x7E (other than CR / LF) in a sentence
    MALFORMED = 4  #: bad framing (no ``*hh``, lower-case/non-hex digits, no CR before LF),
    #: wrong field count, or a field that is not a valid number
    OUT_OF_RANGE = 5  #: syntactically valid numbers outside the protocol's limits
    UNKNOWN_SENTENCE = 6  #: a valid frame whose address is not ``PARVA`` / ``PARVH``
    TRUNCATED = 7  #: a ``$`` (or the end of the stream) before the sentence's LF


@dataclass(frozen=True, slots=True)
class Parva:
    """One decoded ``$PARVA`` sentence: slot ``k`` of ``n`` in epoch ``seq``."""

    offset: int
    seq: int
    n: int
    k: int
    id: int
    d: int
    delta: int


@dataclass(frozen=True, slots=True)
class Parvh:
    """One decoded ``$PARVH`` research sentence: field ``h`` of slot ``k`` in epoch ``seq``."""

    offset: int
    seq: int
    k: int
    id: int
    h: Field


@dataclass(frozen=True, slots=True)
class DecodeError:
    """A rejected sentence (an event, not an exception)."""

    kind: ErrorKind
    offset: int
    length: int


@dataclass(frozen=True, slots=True)
class Epoch:
    """All slots of one ``seq``.

    ``slots[k-1]`` is ``(id, d, delta)``, or ``None`` when slot ``k`` never arrived intact.
    ``complete`` is true only when every slot 1..n arrived and no rejected sentence came
    between the first and the last of them. ``fields`` is ``None`` unless at least one
    ``$PARVH`` was attached; then ``fields[k-1]`` is ``(hx, hy, hz)`` or ``None``.
    ``gap`` is how many seq values were skipped before this epoch (modulo 65536).
    """

    seq: int
    n: int
    complete: bool
    slots: tuple[Slot | None, ...]
    fields: tuple[Field | None, ...] | None = None
    gap: int = 0

    def to_json(self) -> dict:
        """The ``arva-bench cat`` object: ``{"seq", "complete", "slots"[, "field"]}``."""
        out: dict = {"seq": self.seq, "complete": self.complete,
                     "slots": [None if s is None else list(s) for s in self.slots]}
        if self.fields is not None:
            out["field"] = [None if f is None else list(f) for f in self.fields]
        return out


Event = Parva | Parvh | DecodeError | Epoch


@dataclass
class DecoderStats:
    """Running counters of a decoder (mutable; read them at any time)."""

    bytes: int = 0  #: bytes fed so far
    garbage_bytes: int = 0  #: bytes outside any sentence (skipped while looking for ``$``)
    sentences_ok: int = 0  #: valid ``$PARVA`` + ``$PARVH`` sentences
    errors: dict[ErrorKind, int] = field(default_factory=lambda: {k: 0 for k in ErrorKind})
    epochs_complete: int = 0
    epochs_incomplete: int = 0
    seq_gaps: int = 0  #: epochs whose seq was not the previous seq + 1 (mod 65536)
    seqs_missing: int = 0  #: sum of the gaps: seq values never seen
    seq_wraps: int = 0  #: epochs whose seq is below the previous one: 65535 -> 0 passed (or a restart)
    fields_orphaned: int = 0  #: valid ``$PARVH`` with no matching slot to attach to

    @property
    def errors_total(self) -> int:
        return sum(self.errors.values())

    def as_dict(self) -> dict[str, int]:
        """Flat ``name -> count`` mapping (error kinds as ``errors.<KIND>``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "errors"}
        for kind in ErrorKind:
            out[f"errors.{kind.name}"] = self.errors[kind]
        return out
