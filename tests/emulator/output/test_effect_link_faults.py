"""The ``link_faults`` effect: a FaultyPort around an in-memory port, fake clock and sleep.

Rates are checked over ~1e6 bytes (or ~2e4 writes) with binomial 5-sigma bounds.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.output.link_faults import SPLIT_GAP_S, FaultyPort, LinkFaultConfig
from emulator.output.ports import Port
from firmware_proto.errors import InputError


class MemPort(Port):
    """Keeps every write; accepts up to ``capacity`` bytes of each (None: all)."""

    path = "mem://test"

    def __init__(self, label="arva", capacity=None, clock=None):
        super().__init__(label)
        self.capacity = capacity
        self.clock = clock
        self.writes: list[bytes] = []
        self.events: list[tuple[str, float | None]] = []
        self.drain_wait = None
        self.down = False

    def write(self, data):
        assert not self.down, "written while disconnected"
        take = len(data) if self.capacity is None else min(len(data), self.capacity)
        self.writes.append(bytes(data[:take]))
        return self._account(len(data), take)

    def disconnect(self):
        self.down = True
        self.events.append(("disconnect", self.clock() if self.clock else None))

    def reconnect(self):
        self.down = False
        self.events.append(("reconnect", self.clock() if self.clock else None))

    def set_drain_wait(self, seconds):
        self.drain_wait = seconds

    def pending(self):
        return 17

    @property
    def received(self):
        return b"".join(self.writes)


class Clock:
    def __init__(self, t=0.0):
        self.t = t

    def __call__(self):
        return self.t


class Sleeps(list):
    def __call__(self, seconds):
        self.append(seconds)


def make(cfg, seed=1, stream=0, capacity=None, clock=None):
    clock = clock or Clock()
    inner = MemPort(capacity=capacity, clock=clock)
    sleeps = Sleeps()
    return FaultyPort(inner, cfg, seed, stream, sleep=sleeps, clock=clock), inner, sleeps


def payloads(count, size, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, size, dtype=np.uint8).tobytes() for _ in range(count)]


def send_a_megabyte(cfg, seed):
    """A faulty port (``cfg``, ``seed``) after 1000 writes of 1000 random bytes:
    (port, the port beneath it, the writes)."""
    port, inner, _ = make(cfg, seed=seed)
    data = payloads(1000, 1000)
    for d in data:
        port.write(d)
    return port, inner, data


def within_5_sigma(k, n, p):
    return abs(k - n * p) <= 5 * math.sqrt(n * p * (1 - p))


def accounted(port):
    s = port.summary()
    return s["bytes_written"] + s["bytes_dropped"] == s["bytes_offered"]


# --- configuration ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"loss": 1.5}, "link_faults.loss: must be a probability in [0, 1], got 1.5"),
        ({"corrupt": -0.1}, "link_faults.corrupt: must be a probability in [0, 1], got -0.1"),
        ({"split": float("nan")}, "link_faults.split: must be a probability in [0, 1], got nan"),
        ({"stall": "often"}, "link_faults.stall: must be a probability in [0, 1], got 'often'"),
        ({"stall_ms": -1}, "link_faults.stall_ms: must be >= 0, got -1"),
        ({"disconnect_every_s": -5}, "link_faults.disconnect_every_s: must be >= 0 (0 = never), got -5"),
        ({"disconnect_s": 0}, "link_faults.disconnect_s: must be > 0, got 0"),
        ({"disconnect_every_s": 2, "disconnect_s": 2}, "link_faults.disconnect_s: must be < disconnect_every_s (2), got 2"),
    ],
)
def test_config_rejects(kwargs, message):
    with pytest.raises(InputError) as err:
        LinkFaultConfig(**kwargs)
    assert str(err.value) == message


# --- pass-through and plumbing -------------------------------------------------------------


def test_no_faults_is_a_transparent_wrapper():
    port, inner, sleeps = make(LinkFaultConfig())
    data = payloads(50, 100)
    for d in data:
        assert port.write(d) == 100
    assert inner.writes == data and sleeps == []
    assert port._rng_stall is None and port._rng_bytes is None and port._rng_split is None
    assert port.faults_injected == 0 and accounted(port)
    assert isinstance(port, Port) and port.label == "arva" and port.path == "mem://test"
    assert port.pending() == 17  # port-specific methods read through
    port.set_drain_wait(0.05)
    assert inner.drain_wait == 0.05


def test_bytes_the_wrapped_port_drops_are_counted():
    port, inner, _ = make(LinkFaultConfig(loss=0.1), capacity=30)
    for d in payloads(200, 100):
        assert port.write(d) <= 30
    assert port.bytes_written == inner.bytes_written == len(inner.received)
    assert accounted(port)
    assert port.bytes_dropped == port.bytes_lost + inner.bytes_dropped


def test_seeded_reproducibility():
    cfg = LinkFaultConfig(loss=0.05, corrupt=0.05, split=0.3, stall=0.2, stall_ms=50)
    data = payloads(300, 80)
    runs = []
    for seed in (9, 9, 10):
        port, inner, sleeps = make(cfg, seed=seed)
        for d in data:
            port.write(d)
        runs.append((inner.writes, list(sleeps), port.summary()))
    assert runs[0] == runs[1]
    assert runs[0][0] != runs[2][0]
    port, inner, _ = make(cfg, seed=9, stream=1)  # another port of the same scene
    for d in data:
        port.write(d)
    assert inner.writes != runs[0][0]


@settings(max_examples=60)
@given(st.lists(st.integers(1, 700), min_size=1, max_size=30), st.booleans())
def test_byte_faults_do_not_depend_on_how_the_stream_is_cut_into_writes(cuts, split):
    """Speed 0 writes thousands of epochs at once, real time one per write: the same
    stream must carry the same faulted bytes either way (splits and stalls included)."""
    cfg = LinkFaultConfig(loss=0.05, corrupt=0.08, split=0.5 if split else 0.0, stall=0.3 if split else 0.0)
    data = b"".join(payloads(40, 81, seed=4))
    whole, inner_whole, _ = make(cfg, seed=21)
    whole.write(data)
    pieces, inner_pieces, _ = make(cfg, seed=21)
    pos = 0
    for n in cuts * (len(data) // sum(cuts) + 1):
        if pos >= len(data):
            break
        pieces.write(data[pos : pos + n])
        pos += n
    assert inner_pieces.received == inner_whole.received
    assert (pieces.bytes_lost, pieces.bytes_corrupted) == (whole.bytes_lost, whole.bytes_corrupted)


# --- byte faults ----------------------------------------------------------------------------


def is_subsequence(small, big):
    it = iter(big)
    return all(b in it for b in small)


def test_loss_rate_and_order_preserved():
    p = 0.03
    port, inner, data = send_a_megabyte(LinkFaultConfig(loss=p), seed=2)
    n = 1_000_000
    assert within_5_sigma(port.bytes_lost, n, p)
    assert len(inner.received) + port.bytes_lost == n and accounted(port)
    assert port.bytes_written == n - port.bytes_lost
    # What arrives is each write with bytes removed, in order, unchanged.
    assert all(is_subsequence(got, sent) for got, sent in zip(inner.writes[:100], data[:100]))


def test_corruption_rate_and_every_corrupted_byte_changes():
    p = 0.01
    port, inner, data = send_a_megabyte(LinkFaultConfig(corrupt=p), seed=3)
    sent = np.frombuffer(b"".join(data), np.uint8)
    got = np.frombuffer(inner.received, np.uint8)
    assert got.size == sent.size
    xor = sent ^ got
    changed = np.count_nonzero(xor)
    assert changed == port.bytes_corrupted  # a corrupted byte always differs
    assert within_5_sigma(changed, sent.size, p)
    # XOR values uniform on 1..255: chi-square with 254 dof within 5 sigma (sd sqrt(508)).
    counts = np.bincount(xor[xor != 0], minlength=256)[1:]
    expected = changed / 255
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert abs(chi2 - 254) < 5 * math.sqrt(2 * 254)


def test_loss_and_corruption_together():
    port, inner, _ = send_a_megabyte(LinkFaultConfig(loss=0.1, corrupt=0.02), seed=4)
    n = 1_000_000
    assert within_5_sigma(port.bytes_lost, n, 0.1)
    kept = n - port.bytes_lost
    assert len(inner.received) == kept and accounted(port)
    # Corruption applies to the bytes that survive.
    assert within_5_sigma(port.bytes_corrupted, kept, 0.02)


def test_full_loss_and_empty_writes():
    port, inner, _ = make(LinkFaultConfig(loss=1.0, corrupt=1.0), seed=4)
    assert port.write(b"hello") == 0 and port.write(b"") == 0
    assert port.bytes_lost == 5 and port.bytes_corrupted == 0 and accounted(port)


# --- split writes -------------------------------------------------------------------------------


def test_split_rate_piece_counts_and_concatenation():
    p, writes, size = 0.25, 20_000, 50
    cfg = LinkFaultConfig(split=p, corrupt=0.01)
    port, inner, sleeps = make(cfg, seed=5)
    # Same seed without splits: the byte faults come from their own stream.
    plain, plain_inner, _ = make(LinkFaultConfig(corrupt=0.01), seed=5)
    pieces_per_write = []
    for d in payloads(writes, size):
        before = len(inner.writes)
        port.write(d)
        plain.write(d)
        pieces_per_write.append(len(inner.writes) - before)
    assert inner.received == plain_inner.received  # pieces concatenate to the faulted data
    assert all(len(w) > 0 for w in inner.writes)
    k = np.array(pieces_per_write)
    n_split = int((k > 1).sum())
    assert n_split == port.writes_split
    assert within_5_sigma(n_split, writes, p)
    assert set(k.tolist()) <= {1, 2, 3, 4}
    for pieces in (2, 3, 4):
        assert within_5_sigma(int((k == pieces).sum()), n_split, 1 / 3)
    # One gap between consecutive pieces, nothing else.
    assert sleeps == [SPLIT_GAP_S] * int((k - 1).sum())


def test_split_cut_points_uniform():
    port, inner, _ = make(LinkFaultConfig(split=1.0), seed=6)
    firsts = []
    for d in payloads(6000, 11):
        before = len(inner.writes)
        port.write(d)
        if len(inner.writes) - before == 2:
            firsts.append(len(inner.writes[before]))
    # Two pieces: the cut is uniform on 1..10, mean 5.5, variance (10^2 - 1) / 12.
    firsts = np.array(firsts)
    assert firsts.min() == 1 and firsts.max() == 10
    assert abs(firsts.mean() - 5.5) < 5 * math.sqrt(99 / 12 / firsts.size)


def test_split_of_short_writes():
    port, inner, _ = make(LinkFaultConfig(split=1.0), seed=6)
    port.write(b"x")
    port.write(b"ab")
    assert inner.writes == [b"x", b"a", b"b"]


# --- stalls ---------------------------------------------------------------------------------------


def test_stall_sleeps_stall_ms_with_the_configured_probability():
    p, writes = 0.1, 20_000
    port, inner, sleeps = make(LinkFaultConfig(stall=p, stall_ms=250), seed=7)
    for d in payloads(writes, 5):
        port.write(d)
    assert sleeps == [0.25] * port.stalls
    assert within_5_sigma(port.stalls, writes, p)
    assert len(inner.received) == 5 * writes


# --- disconnects ---------------------------------------------------------------------------------


def test_disconnect_schedule_exact():
    clock = Clock()
    port, inner, _ = make(LinkFaultConfig(disconnect_every_s=10, disconnect_s=2), clock=clock)
    data = b"$PARVA,0,1,1,-1,-1,-1*78\r\n"
    for i in range(100):  # t = 0, 0.5, ..., 49.5
        clock.t = i * 0.5
        port.write(data)
        assert port.disconnected == (clock.t >= 10 and clock.t % 10 < 2)
    assert inner.events == [
        ("disconnect", 10.0), ("reconnect", 12.0),
        ("disconnect", 20.0), ("reconnect", 22.0),
        ("disconnect", 30.0), ("reconnect", 32.0),
        ("disconnect", 40.0), ("reconnect", 42.0),
    ]  # fmt: skip
    assert port.disconnects == 4
    dropped_writes = 4 * 4  # t = k0, k0.5, k1, k1.5 for k = 1..4
    assert port.bytes_disconnected == dropped_writes * len(data) == port.bytes_dropped
    assert inner.received == data * (100 - dropped_writes) and accounted(port)


def test_outage_between_writes_is_still_applied_and_poll_ends_outages():
    clock = Clock()
    port, inner, _ = make(LinkFaultConfig(disconnect_every_s=10, disconnect_s=2), clock=clock)
    for t in (9.0, 13.0, 25.0):  # no write inside [10, 12) or [20, 22)
        clock.t = t
        port.write(b"abc")
    assert inner.events == [("disconnect", 13.0), ("reconnect", 13.0), ("disconnect", 25.0), ("reconnect", 25.0)]
    assert inner.received == b"abc" * 3
    clock.t = 30.5
    port.write(b"lost")
    clock.t = 32.0
    port.poll()
    assert inner.events[-2:] == [("disconnect", 30.5), ("reconnect", 32.0)]
    assert not port.disconnected and port.disconnects == 3 and port.bytes_disconnected == 4


def test_port_that_cannot_disconnect_gets_a_simulated_outage():
    class Plain(Port):
        def __init__(self):
            super().__init__("gps:rx")
            self.got = b""

        def write(self, data):
            self.got += data
            return self._account(len(data), len(data))

    clock = Clock()
    inner = Plain()
    port = FaultyPort(inner, LinkFaultConfig(disconnect_every_s=5, disconnect_s=1), 1, sleep=Sleeps(), clock=clock)
    for t in (4.0, 5.0, 5.5, 6.0):
        clock.t = t
        port.write(b"x")
    assert inner.got == b"xx" and port.bytes_disconnected == 2 and port.disconnects == 1 and accounted(port)


def test_faults_injected_sums_the_counters():
    cfg = LinkFaultConfig(loss=0.05, corrupt=0.05, split=0.2, stall=0.1)
    port, _, _ = make(cfg, seed=8)
    for d in payloads(500, 40):
        port.write(d)
    s = port.summary()
    assert port.faults_injected == s["bytes_lost"] + s["bytes_corrupted"] + s["writes_split"] + s["stalls"] + s["disconnects"]
    assert min(s["bytes_lost"], s["bytes_corrupted"], s["writes_split"], s["stalls"]) > 0
    assert s["writes"] == 500 and s["bytes_offered"] == 20_000
