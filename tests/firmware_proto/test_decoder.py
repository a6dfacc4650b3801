"""The Python streaming decoder and epoch assembler: exact cases and hostile-stream properties."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import firmware_proto.decoder as decoder_mod
from firmware_proto.decoder import Decoder, decode, parse_line
from firmware_proto.events import DecodeError, Epoch, ErrorKind, Parva, Parvh
from firmware_proto.sentences import encode_epoch, encode_parvh, frame
from hostile_streams import EMPTY, EpochSpec, Stream, fields, hostile_streams, slots, split

BRIEF_SLOT = b"$PARVA,0,1,1,1,1905,21*5B\r\n"
BRIEF_EMPTY = b"$PARVA,0,1,1,-1,-1,-1*78\r\n"


def feed_all(chunks: list[bytes], expect_fields: bool = False) -> tuple[list, Decoder]:
    dec = Decoder(expect_fields=expect_fields)
    events = []
    for c in chunks:
        events += dec.feed(c)
    events += dec.flush()
    return events, dec


# -- exact cases -------------------------------------------------------------------------


def test_brief_examples_decode_exactly() -> None:
    events, stats = decode(BRIEF_SLOT + BRIEF_EMPTY)
    assert events == [
        Parva(0, 0, 1, 1, 1, 1905, 21),
        Epoch(0, 1, True, ((1, 1905, 21),), None, 0),
        Parva(27, 0, 1, 1, -1, -1, -1),
        Epoch(0, 1, True, (EMPTY,), None, 0),
    ]
    assert (stats.sentences_ok, stats.epochs_complete, stats.errors_total, stats.bytes) == (2, 2, 0, 53)


def test_parse_line_kinds() -> None:
    assert parse_line(BRIEF_SLOT, 7) == Parva(7, 0, 1, 1, 1, 1905, 21)
    assert parse_line(b"$PARVA,0,1,1,1,1905,21*5C\r\n") is ErrorKind.BAD_CHECKSUM
    assert parse_line(b"$PARVA,0,1,1,1,1905,21*5b\r\n") is ErrorKind.MALFORMED
    assert parse_line(b"$PARVA,0,1,1,1,1905,21*5B\n") is ErrorKind.MALFORMED
    assert parse_line(frame("PARVA,0,1,1,1,1905,090")) is ErrorKind.MALFORMED
    assert parse_line(frame("PARVA,0,1,1,1,1905,90")) is ErrorKind.OUT_OF_RANGE
    assert parse_line(frame("PARVB,0,1,1,1,1905,21")) is ErrorKind.UNKNOWN_SENTENCE
    h = parse_line(encode_parvh(3, 2, 9, (1.5, -2.0, 1e-300)), 5)
    assert h == Parvh(5, 3, 2, 9, (1.5, -2.0, 1e-300))


def test_error_events_carry_kind_offset_and_length() -> None:
    data = b"xx$PARVA,0,1$" + BRIEF_SLOT[1:] + b"$PARVA,0,1,1,1,19\xff"
    events, stats = decode(data)
    assert events == [
        DecodeError(ErrorKind.TRUNCATED, 2, 10),
        Parva(12, 0, 1, 1, 1, 1905, 21),
        Epoch(0, 1, True, ((1, 1905, 21),), None, 0),
        DecodeError(ErrorKind.NON_ASCII, 39, 18),
    ]
    assert stats.garbage_bytes == 2
    assert stats.errors[ErrorKind.TRUNCATED] == 1 and stats.errors[ErrorKind.NON_ASCII] == 1
    assert stats.errors_total == 2


def test_incomplete_epoch_reports_missing_slots_as_null() -> None:
    data = encode_epoch(4, [(1, 100, 5), (2, 200, -5), (3, 300, 0)])
    lines = data.splitlines(keepends=True)
    events, stats = decode(lines[0] + lines[2])
    (epoch,) = [e for e in events if isinstance(e, Epoch)]
    assert epoch == Epoch(4, 3, False, ((1, 100, 5), None, (3, 300, 0)), None, 0)
    assert epoch.to_json() == {"seq": 4, "complete": False, "slots": [[1, 100, 5], None, [3, 300, 0]]}
    assert (stats.epochs_complete, stats.epochs_incomplete) == (0, 1)


def test_epoch_json_has_field_only_with_parvh() -> None:
    data = encode_epoch(9, [(1, 1905, 21), EMPTY], [(1.5, -0.25, 3e-7), None])
    events, _ = decode(data, expect_fields=True)
    (epoch,) = [e for e in events if isinstance(e, Epoch)]
    assert epoch.to_json() == {
        "seq": 9,
        "complete": True,
        "slots": [[1, 1905, 21], [-1, -1, -1]],
        "field": [[1.5, -0.25, 3e-7], None],
    }


def test_seq_gaps_are_counted_modulo_65536() -> None:
    seqs = [65533, 65534, 65535, 0, 1, 4, 4, 10, 9]
    data = b"".join(encode_epoch(s, [(1, 100, 0)]) for s in seqs)
    events, stats = decode(data)
    gaps = [e.gap for e in events if isinstance(e, Epoch)]
    assert gaps == [0, 0, 0, 0, 0, 2, 0, 5, 65534]
    assert (stats.seq_gaps, stats.seqs_missing) == (3, 2 + 5 + 65534)


def test_held_epoch_is_released_by_idle() -> None:
    dec = Decoder()
    first = encode_epoch(1, [(1, 100, 0), (2, 200, 1)], [(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)])
    events = dec.feed(first)
    # The last $PARVH completes the held epoch at once.
    assert [type(e) for e in events] == [Parva, Parvh, Parva, Parvh, Epoch]
    assert events[-1] == Epoch(1, 2, True, ((1, 100, 0), (2, 200, 1)), ((1.0, 2.0, 3.0), (4.0, 5.0, 6.0)), 0)
    second = encode_epoch(2, [(1, 100, 0), EMPTY], [(1.0, 2.0, 3.0), None])
    events = dec.feed(second)
    assert [type(e) for e in events] == [Parva, Parvh, Parva]  # held: an empty slot has no $PARVH
    (released,) = dec.idle()
    assert released == Epoch(2, 2, True, ((1, 100, 0), EMPTY), ((1.0, 2.0, 3.0), None), 0)
    assert dec.idle() == [] and dec.flush() == []


def test_flush_twice_and_continue_after_flush() -> None:
    dec = Decoder()
    assert dec.feed(b"$PARVA,1") == []
    assert dec.flush() == [DecodeError(ErrorKind.TRUNCATED, 0, 8)]
    assert dec.flush() == []
    events = dec.feed(BRIEF_SLOT)
    assert events[0] == Parva(8, 0, 1, 1, 1, 1905, 21)
    assert dec.offset == 8 + len(BRIEF_SLOT)


def test_never_buffers_more_than_one_sentence() -> None:
    dec = Decoder()
    burst = (b"$" + b"A" * 5000) * 20 + b"\xff" * 10000
    for i in range(0, len(burst), 777):
        dec.feed(burst[i : i + 777])
        assert len(dec._partial) <= 81
    events = dec.feed(BRIEF_SLOT) + dec.flush()
    assert events[-2:] == [Parva(len(burst), 0, 1, 1, 1, 1905, 21), Epoch(0, 1, True, ((1, 1905, 21),), None, 0)]
    assert dec.stats.errors[ErrorKind.TOO_LONG] == 20


# -- properties ------------------------------------------------------------------------------


def _matches(out: Epoch, spec: EpochSpec, exact_fields: bool) -> bool:
    if out.seq != spec.seq or out.n != len(spec.slots) or out.slots != spec.slots:
        return False
    truth = spec.decoded_fields()
    if exact_fields:
        return out.fields == truth
    if out.fields is None:
        return True
    return truth is not None and all(f is None or f == t for f, t in zip(out.fields, truth))


def check_against_truth(stream: Stream, events: list) -> None:
    """Every intact epoch exactly once, complete, in order; nothing wrong reported as data."""
    by_seq = {spec.seq: spec for spec in stream.epochs}
    out_epochs = [e for e in events if isinstance(e, Epoch)]
    for e in out_epochs:  # even incomplete epochs never carry wrong slots
        spec = by_seq.get(e.seq)
        assert spec is not None, f"epoch {e} has a seq that was never sent"
        if e.n == len(spec.slots):
            for got, want in zip(e.slots, spec.slots):
                assert got is None or got == want, e
    matched = []
    j = 0
    for e in (e for e in out_epochs if e.complete):
        while j < len(stream.epochs) and not _matches(e, stream.epochs[j], False):
            j += 1
        assert j < len(stream.epochs), f"complete epoch {e} does not match the input, or is out of order"
        matched.append(j)
        j += 1
    for i, (spec, ok) in enumerate(zip(stream.epochs, stream.intact)):
        if ok:
            assert i in matched, f"intact epoch {spec} was not reported complete"
            (out,) = [e for e in out_epochs if e.complete and e.seq == spec.seq]
            if stream.expect_fields:
                assert _matches(out, spec, True), (out, spec)


def check_byte_accounting(data: bytes, events: list, dec: Decoder) -> None:
    good = sum(data.index(b"\n", e.offset) + 1 - e.offset for e in events if isinstance(e, (Parva, Parvh)))
    bad = sum(e.length for e in events if isinstance(e, DecodeError))
    assert good + bad + dec.stats.garbage_bytes == len(data) == dec.stats.bytes
    assert dec.stats.sentences_ok == sum(isinstance(e, (Parva, Parvh)) for e in events)
    for kind in ErrorKind:
        assert dec.stats.errors[kind] == sum(isinstance(e, DecodeError) and e.kind is kind for e in events)
    out = [e for e in events if isinstance(e, Epoch)]
    assert dec.stats.epochs_complete == sum(e.complete for e in out)
    assert dec.stats.epochs_incomplete == sum(not e.complete for e in out)


@given(hostile_streams(), st.data())
def test_hostile_stream_ground_truth(stream: Stream, data: st.DataObject) -> None:
    cuts = data.draw(st.lists(st.integers(0, len(stream.data)), max_size=6).map(sorted))
    events, dec = feed_all(split(stream.data, cuts), stream.expect_fields)
    check_against_truth(stream, events)
    check_byte_accounting(stream.data, events, dec)


@pytest.mark.slow
@given(hostile_streams(), st.data())
def test_result_does_not_depend_on_chunking(stream: Stream, data: st.DataObject) -> None:
    whole, dec1 = feed_all([stream.data], stream.expect_fields)
    cuts = data.draw(st.lists(st.integers(0, len(stream.data)), max_size=10).map(sorted))
    chunked, dec2 = feed_all(split(stream.data, cuts), stream.expect_fields)
    assert chunked == whole and dec2.stats == dec1.stats
    bytewise, dec3 = feed_all([stream.data[i : i + 1] for i in range(len(stream.data))], stream.expect_fields)
    assert bytewise == whole and dec3.stats == dec1.stats


@given(hostile_streams(max_epochs=6))
def test_vectorised_checksum_path_agrees(stream: Stream) -> None:
    small, _ = feed_all([stream.data], stream.expect_fields)
    old = decoder_mod._PX_MIN
    decoder_mod._PX_MIN = 0  # force the numpy prefix-XOR path even for short buffers
    try:
        forced, _ = feed_all([stream.data], stream.expect_fields)
    finally:
        decoder_mod._PX_MIN = old
    assert forced == small


@given(st.lists(st.tuples(st.lists(slots, min_size=1, max_size=5), st.booleans()), max_size=6), st.integers(0, 65535))
def test_encode_decode_round_trip(epochs: list, seq0: int) -> None:
    data = b"".join(encode_epoch(seq0 + i, s) for i, (s, _) in enumerate(epochs))
    events, stats = decode(data)
    out = [e for e in events if isinstance(e, Epoch)]
    assert [(e.seq, e.slots, e.complete) for e in out] == [
        ((seq0 + i) % 65536, tuple(s), True) for i, (s, _) in enumerate(epochs)
    ]
    assert stats.errors_total == 0 and stats.garbage_bytes == 0 and stats.seq_gaps == 0


@given(st.lists(slots, min_size=1, max_size=4).flatmap(lambda s: st.tuples(st.just(s), st.tuples(*[fields] * len(s)))))
@settings(max_examples=100)
def test_round_trip_with_fields(epoch: tuple) -> None:
    s, f = epoch
    fl = [None if slot == EMPTY else h for slot, h in zip(s, f)]
    events, _ = decode(encode_epoch(77, s, fl), expect_fields=True)
    (out,) = [e for e in events if isinstance(e, Epoch)]
    assert out.complete and out.slots == tuple(s)
    assert out.fields == EpochSpec(77, tuple(s), tuple(fl)).decoded_fields()


def test_fast_and_slow_paths_agree_on_every_single_byte_change() -> None:
    """Every one-byte substitution of a good sentence, decoded via feed() (fast path
    first) and via parse_line() directly, gives the same verdict."""
    line = b"$PARVA,65535,3,2,17,1905,-21*40\r\n"
    assert parse_line(line) == Parva(0, 65535, 3, 2, 17, 1905, -21)
    for pos in range(1, len(line) - 1):
        for b in range(0x20, 0x7F):
            if b == 0x24:
                continue
            mutated = line[:pos] + bytes([b]) + line[pos + 1 :]
            (first, *_) = Decoder().feed(mutated) or [None]
            expected = parse_line(mutated)
            if isinstance(expected, ErrorKind):
                assert first == DecodeError(expected, 0, len(mutated)), mutated
            else:
                assert first == expected, mutated


@pytest.mark.parametrize("bad", [b"\x00", b"\x1f", b"\x7f", b"\x80", b"\xff", b"\t"])
def test_non_printable_bytes_abort_a_sentence(bad: bytes) -> None:
    events, stats = decode(b"$PARVA,0,1" + bad + b"1,1,1905,21*5B\r\n" + BRIEF_SLOT)
    assert events[0] == DecodeError(ErrorKind.NON_ASCII, 0, 11)
    assert isinstance(events[1], Parva) and events[2].complete
