"""What the XOR checksum misses, measured (issue 16; docs/protocol.md "What the checksum misses").

An emulated stream (the paper walk, EMI noise on, 4 channels) is damaged by a seeded
mutation fuzz, one damage per hit sentence, of the kinds a serial line produces:
a flipped bit, a dropped byte, an inserted byte, a repeated byte, an inserted
*doubled* byte pair and two swapped neighbours. A complete epoch the decoder accepts
whose slots differ from what was sent is *corrupt yet accepted*.

XOR is blind to the last two by construction: an inserted pair ``cc`` XORs to 0
(``761`` -> ``76661``: 7.61 m becomes 766.61 m) and a swap does not change the XOR at
all (``761`` -> ``716``). The optional range check (``Decoder(max_d_cm=...)``, C
``arva_decoder_set_max_range``) rejects readings beyond the receiver's maximum range,
which catches most of the inserted pairs (they multiply d by ~100).

The Python and C decoders must agree event for event, with and without the check.
"""

from __future__ import annotations

import numpy as np
import pytest

from emulator.receiver.receiver import Receiver
from emulator.scene.reader import load_scene
from firmware_proto.decoder import Decoder
from firmware_proto.events import Epoch, Parva
from firmware_proto.golden import event_text
from firmware_proto.sentences import encode_epochs

from c_codec import CDecoder, find_cc

EPOCHS = 3000
KINDS = ("flip", "drop", "insert", "repeat", "pair", "swap")
SCENE = "emulator/scenes/paper_walk.toml"


def _stream() -> tuple[bytes, dict[int, tuple]]:
    scene = load_scene(SCENE)
    scene = type(scene)(**{**scene.__dict__, "effects": type(scene.effects)(noise=True)})
    ep = Receiver(scene).next_batch(EPOCHS).epochs
    data = encode_epochs(0, ep.ids, ep.d, ep.delta)
    truth = {k: tuple((int(i), int(d), int(a)) for i, d, a in zip(ep.ids[k], ep.d[k], ep.delta[k])) for k in range(EPOCHS)}
    return data, truth


def _mutate(data: bytes, kinds: tuple[str, ...], seed: int, hit: float) -> bytes:
    """Damage each sentence with probability ``hit``, by one mutation inside its body."""
    rng = np.random.Generator(np.random.PCG64(seed))
    out = bytearray()
    for line in data.split(b"\n")[:-1]:
        s = bytearray(line + b"\n")
        if rng.random() < hit:
            kind = kinds[int(rng.integers(len(kinds)))]
            i = int(rng.integers(1, len(s) - 6))  # inside "PARVA,...": not '$', '*hh', CR LF
            if kind == "flip":
                s[i] ^= 1 << int(rng.integers(8))
            elif kind == "drop":
                del s[i]
            elif kind == "insert":
                s.insert(i, int(rng.integers(0x20, 0x7F)))
            elif kind == "repeat":
                s.insert(i, s[i])
            elif kind == "pair":
                c = int(rng.integers(0x30, 0x3A))  # a digit, doubled
                s[i:i] = bytes([c, c])
            else:  # swap
                s[i], s[i + 1] = s[i + 1], s[i]
        out += s
    return bytes(out)


def _wrong_sentences(events, truth) -> int:
    """Accepted $PARVA whose content is not what was sent in that (seq, k)."""
    wrong = 0
    for e in events:
        if type(e) is Parva:
            sent = truth.get(e.seq)
            if sent is None or e.n != len(sent) or sent[e.k - 1] != (e.id, e.d, e.delta):
                wrong += 1
    return wrong


def _corrupt_accepted(events, truth) -> tuple[int, int]:
    complete = [e for e in events if type(e) is Epoch and e.complete]
    bad = sum(1 for e in complete if tuple(e.slots) != truth.get(e.seq))
    return bad, len(complete)


def _decode(data: bytes, max_d_cm: int | None):
    dec = Decoder() if max_d_cm is None else Decoder(max_d_cm=max_d_cm)
    return dec.feed(data) + dec.flush()


@pytest.fixture(scope="module")
def stream():
    return _stream()


#: Sentence level: every sentence damaged once by one kind (seed 16 + kind index):
#: kind -> (accepted with wrong content, of EPOCHS * 4 damaged) without / with the range check.
EXPECTED_SENTENCES = {
    "flip": (0, 0), "drop": (0, 0), "insert": (0, 0), "repeat": (0, 0), "pair": (2410, 988), "swap": (2513, 2343),
}
#: Epoch level: a line damaging 1 % of sentences with any kind (seed 99):
#: (corrupt yet accepted, complete epochs) without / with the range check.
EXPECTED_EPOCHS = ((6, 2908), (4, 2906))


@pytest.mark.slow
def test_checksum_blind_spots_are_measured(stream):
    data, truth = stream
    n_sentences = data.count(b"\n")
    assert _corrupt_accepted(_decode(data, None), truth) == (0, EPOCHS)
    sentences = {}
    for seed, kind in enumerate(KINDS, start=16):
        damaged = _mutate(data, (kind,), seed, 1.0)
        sentences[kind] = (_wrong_sentences(_decode(damaged, None), truth), _wrong_sentences(_decode(damaged, 5000), truth))
    mixed = _mutate(data, KINDS, 99, 0.01)
    epochs = (_corrupt_accepted(_decode(mixed, None), truth), _corrupt_accepted(_decode(mixed, 5000), truth))
    print()
    for kind, (bad, bad_r) in sentences.items():
        print(f"{kind:8} {bad:5} / {n_sentences} ({100 * bad / n_sentences:.2f} %)   with range check {bad_r:5} ({100 * bad_r / n_sentences:.2f} %)")
    print("epochs", epochs)
    # Single-byte damage always changes the XOR (or the framing): never accepted.
    for kind in ("flip", "drop", "insert", "repeat"):
        assert sentences[kind] == (0, 0), kind
    assert sentences == EXPECTED_SENTENCES
    assert epochs == EXPECTED_EPOCHS


def test_python_and_c_decoders_agree_on_damaged_streams(stream):
    if find_cc() is None:
        pytest.skip("no C compiler")
    data, _ = stream
    damaged = _mutate(data, KINDS, 99, 0.05)
    for max_d in (None, 5000):
        py = [event_text(e) for e in _decode(damaged, max_d)]
        c = CDecoder(max_d_cm=max_d)
        assert c.feed(damaged) + c.flush() == py


def test_range_check_rejects_the_doubled_pair():
    line = b"$PARVA,0,1,1,1,761,-62*4C\r\n"
    pair = line.replace(b",761,", b",76661,")
    assert pair[-5:] == line[-5:]  # same checksum: XOR cannot tell
    (ev,) = [e for e in Decoder().feed(pair) if type(e).__name__ == "Parva"]
    assert ev.d == 76661
    dec = Decoder(max_d_cm=5000)
    events = dec.feed(pair)
    assert [event_text(e) for e in events] == [f"error OUT_OF_RANGE 0 {len(pair)}"]
    assert [event_text(e) for e in Decoder(max_d_cm=5000).feed(line)][0] == "parva 0 0 1 1 1 761 -62"
    with pytest.raises(ValueError):
        Decoder(max_d_cm=10**7)
