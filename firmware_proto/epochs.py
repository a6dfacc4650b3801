"""Epoch assembly: group decoded sentences into epochs (all slots of one seq).

The rules, identical in the C codec (``arva_codec.c``), are docs/protocol.md section 3:
a ``$PARVA`` joins the epoch being assembled when seq and n match and k rises, else that
epoch is emitted first; the last slot emits it, or holds it for its ``$PARVH`` once one
has been seen (``expect_fields``); a rejected sentence inside it makes it incomplete;
``gap = (seq - previous_seq - 1) mod 65536``.
"""

from __future__ import annotations

from .events import DecodeError, DecoderStats, Epoch, Event, Field, Parva, Parvh, Slot
from .sentences import SEQ_MODULO


class _Pending:
    __slots__ = ("seq", "n", "slots", "fields", "last_k", "tainted", "gap")

    def __init__(self, seq: int, n: int, gap: int) -> None:
        self.seq = seq
        self.n = n
        self.slots: list[Slot | None] = [None] * n
        self.fields: list[Field | None] | None = None
        self.last_k = 0
        self.tainted = False
        self.gap = gap


class EpochAssembler:
    """Turns the sentence-level events of one stream into :class:`Epoch` events.

    Each ``on_*`` method appends to ``out``, in stream order, the events it produces:
    the event itself plus any epoch it completes or releases.
    """

    def __init__(self, stats: DecoderStats | None = None, expect_fields: bool = False) -> None:
        self.stats = stats if stats is not None else DecoderStats()
        self.expect_fields = expect_fields
        self._cur: _Pending | None = None
        self._holding = False
        self._last_seq: int | None = None

    # -- events ------------------------------------------------------------------------
    def on_parva(self, p: Parva, out: list[Event]) -> None:
        cur = self._cur
        if cur is not None:
            if not self._holding and p.seq == cur.seq and p.n == cur.n and p.k > cur.last_k:
                out.append(p)
                self._add(p, out)
                return
            self._emit(out)
        out.append(p)
        self._start(p)
        self._add(p, out)

    def on_parvh(self, h: Parvh, out: list[Event]) -> None:
        self.expect_fields = True
        cur = self._cur
        slot = cur.slots[h.k - 1] if cur is not None and h.seq == cur.seq and h.k <= cur.n else None
        if slot is not None and slot[0] == h.id and (cur.fields is None or cur.fields[h.k - 1] is None):
            if cur.fields is None:
                cur.fields = [None] * cur.n
            cur.fields[h.k - 1] = h.h
            out.append(h)
            if self._holding:
                self._emit(out)
            return
        self.stats.fields_orphaned += 1
        if self._holding:
            self._emit(out)
        out.append(h)

    def on_error(self, e: DecodeError, out: list[Event]) -> None:
        if self._holding:
            self._emit(out)
        elif self._cur is not None:
            self._cur.tainted = True
        out.append(e)

    def idle(self, out: list[Event]) -> None:
        """The line went quiet: release an epoch held for its last ``$PARVH``."""
        if self._holding:
            self._emit(out)

    def flush(self, out: list[Event]) -> None:
        """End of stream: emit whatever epoch is being assembled."""
        if self._cur is not None:
            self._emit(out)

    # -- internals -----------------------------------------------------------------------
    def _start(self, p: Parva) -> None:
        """A new epoch, begun by ``p`` (its slot added by the caller)."""
        last = self._last_seq
        gap = 0
        if last is not None and p.seq != last:
            gap = (p.seq - last - 1) % SEQ_MODULO
            if gap:
                self.stats.seq_gaps += 1
                self.stats.seqs_missing += gap
            if p.seq < last:
                self.stats.seq_wraps += 1
        self._last_seq = p.seq
        self._cur = _Pending(p.seq, p.n, gap)

    def _add(self, p: Parva, out: list[Event]) -> None:
        """``p``'s slot joins the current epoch; the last slot emits it or holds it."""
        cur = self._cur
        cur.slots[p.k - 1] = (p.id, p.d, p.delta)
        cur.last_k = p.k
        if p.k == cur.n:
            if self.expect_fields:
                self._holding = True
            else:
                self._emit(out)

    def _emit(self, out: list[Event]) -> None:
        cur = self._cur
        assert cur is not None
        complete = not cur.tainted and None not in cur.slots
        if complete:
            self.stats.epochs_complete += 1
        else:
            self.stats.epochs_incomplete += 1
        fields = None if cur.fields is None else tuple(cur.fields)
        out.append(Epoch(cur.seq, cur.n, complete, tuple(cur.slots), fields, cur.gap))
        self._cur = None
        self._holding = False
