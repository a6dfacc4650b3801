"""The ``pulses`` effect: pulse timing, overlap hiding, statistics, determinism.

Expected values come from the timing model (pulse n of j on over [phi + nP, phi + nP + W])
worked out by hand, or from a brute-force per-pulse reference written independently of
the vectorised implementation.
"""

import math

import numpy as np
import pytest

from emulator.receiver.pulses import PulseConfig, PulseEffect
from firmware_proto.errors import InputError


def windows(k0, k1, rate_hz):
    """Epoch windows (t_prev, t_now] = ((k-1)/rate, k/rate] for k in [k0, k1)."""
    k = np.arange(k0, k1, dtype=np.float64)
    return (k - 1) / rate_hz, k / rate_hz


def run(effect, k0, k1, rate_hz=1.0, strength=None, present=None):
    t_prev, t_now = windows(k0, k1, rate_hz)
    m = effect.ids.size
    if strength is None:
        strength = np.zeros((t_now.size, m))
    if present is None:
        present = np.ones((t_now.size, m), dtype=bool)
    return effect.reported(t_prev, t_now, strength, present)


def reference(effect, t_prev, t_now, strength, present):
    """Per pulse, in plain Python: which pulses end in each window and which are hidden."""
    P, ph, W, ids = effect.periods_s, effect.phases_s, effect.pulse_s, effect.ids
    mode = effect.config.overlap
    n, m = strength.shape
    out = np.zeros((n, m), dtype=bool)
    hidden_total = 0
    for e in range(n):
        for j in range(m):
            if not present[e, j]:
                continue
            lo = math.floor((t_prev[e] - ph[j] - W) / P[j]) - 2
            hi = math.ceil((t_now[e] - ph[j] - W) / P[j]) + 2
            for pn in range(lo, hi + 1):
                a = ph[j] + float(pn) * P[j]
                if not t_prev[e] < a + W <= t_now[e]:
                    continue
                hidden = False
                for i in range(m):
                    if i == j or not present[e, i]:
                        continue
                    if mode == "weaker":
                        stronger = strength[e, i] > strength[e, j] or (
                            strength[e, i] == strength[e, j] and ids[i] < ids[j]
                        )
                        if not stronger:
                            continue
                    c = math.floor((a - ph[i]) / P[i])
                    for q in range(c - 2, c + 3):
                        b = ph[i] + float(q) * P[i]
                        if b < a + W and a < b + W:
                            hidden = True
                hidden_total += hidden
                out[e, j] |= not hidden
    return out, hidden_total


# --- configuration ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"pulse_ms": 50}, "pulses.pulse_ms: must be >= 70, got 50"),
        ({"pulse_ms": float("nan")}, "pulses.pulse_ms: must be >= 70, got nan"),
        ({"pulse_ms": 301}, "pulses.pulse_ms: must leave >= 400 ms off in the shortest period (700 ms), got 301"),
        (
            {"period_ms": (1000, 1300), "periods_ms": {4: 800}, "pulse_ms": 450},
            "pulses.pulse_ms: must leave >= 400 ms off in the shortest period (800 ms), got 450",
        ),
        ({"period_ms": (600, 1000)}, "pulses.period_ms: must be [lo, hi] with 700 <= lo <= hi <= 1300, got (600, 1000)"),
        ({"period_ms": (1200, 1000)}, "pulses.period_ms: must be [lo, hi] with 700 <= lo <= hi <= 1300"),
        ({"period_ms": 1000}, "pulses.period_ms: must be [lo, hi]"),
        ({"periods_ms": {3: 1400}}, "pulses.periods_ms.3: must be in [700, 1300], got 1400"),
        ({"periods_ms": {"x": 1000}}, "pulses.periods_ms: keys must be transmitter ids, got 'x'"),
        ({"periods_ms": {-1: 1000}}, "pulses.periods_ms: keys must be transmitter ids, got -1"),
        ({"periods_ms": [1000]}, "pulses.periods_ms: must be a table of id = milliseconds"),
        ({"phases_ms": {2: -5}}, "pulses.phases_ms.2: must be >= 0, got -5"),
        ({"phases_ms": {2: "a"}}, "pulses.phases_ms.2: must be a finite number, got 'a'"),
        ({"drift_ppm": -1}, "pulses.drift_ppm: must be in [0, 1000], got -1"),
        ({"drift_ppm": 5000}, "pulses.drift_ppm: must be in [0, 1000], got 5000"),
        ({"overlap": "stronger"}, "pulses.overlap: must be \"weaker\" or \"both\", got 'stronger'"),
    ],
)
def test_config_rejects(kwargs, message):
    with pytest.raises(InputError) as err:
        PulseConfig(**kwargs)
    assert str(err.value).startswith(message)


def test_config_accepts_toml_style_keys_and_is_read_only():
    cfg = PulseConfig(period_ms=[900, 1100], periods_ms={"7": 1000}, phases_ms={"7": 250})
    assert cfg.period_ms == (900.0, 1100.0)
    assert dict(cfg.periods_ms) == {7: 1000.0} and dict(cfg.phases_ms) == {7: 250.0}
    with pytest.raises(TypeError):
        cfg.periods_ms[8] = 1000.0
    # The ETSI extremes are allowed: 70 ms on, 400 ms off in a 700 ms period... and more.
    PulseConfig(period_ms=(700, 700), pulse_ms=300)
    PulseConfig(pulse_ms=70)


def test_effect_rejects_bad_ids_and_shapes():
    with pytest.raises(InputError, match="distinct"):
        PulseEffect(PulseConfig(), [1, 1], 0)
    eff = PulseEffect(PulseConfig(), [1, 2], 0)
    with pytest.raises(InputError, match=r"strength and present must be \(3, 2\)"):
        eff.reported(np.zeros(3), np.ones(3), np.zeros((3, 3)), np.ones((3, 2), bool))


# --- timing draws -----------------------------------------------------------------------


def test_periods_and_phases_are_uniform_and_in_range():
    m = 4000
    eff = PulseEffect(PulseConfig(period_ms=(800, 1200)), np.arange(m), seed=11)
    p = eff.periods_s * 1000
    assert p.min() >= 800 and p.max() <= 1200
    # Uniform on [800, 1200]: mean 1000, sd 400/sqrt(12); 5-sigma bound on the mean.
    assert abs(p.mean() - 1000) < 5 * (400 / math.sqrt(12)) / math.sqrt(m)
    frac = eff.phases_s / eff.periods_s
    assert frac.min() >= 0 and frac.max() < 1
    assert abs(frac.mean() - 0.5) < 5 * math.sqrt(1 / 12 / m)
    # Uniform on [0, 1): variance 1/12, sd of the sample variance sqrt((1/80 - 1/144) / m).
    assert abs(frac.var() - 1 / 12) < 5 * math.sqrt((1 / 80 - 1 / 144) / m)


def test_drift_scales_periods_uniformly_within_ppm():
    m, ppm = 4000, 200.0
    eff = PulseEffect(PulseConfig(periods_ms={i: 1000 for i in range(m)}, drift_ppm=ppm), np.arange(m), 5)
    err = eff.periods_s / 1.0 - 1.0
    a = ppm * 1e-6
    assert np.all(np.abs(err) <= a * (1 + 1e-9))
    assert abs(err.mean()) < 5 * a / math.sqrt(3 * m)  # uniform on [-a, a]: var a^2/3
    # Sample variance of a uniform: sd(s^2) = sqrt((mu4 - sigma^4) / m), mu4 = a^4 / 5.
    assert abs(err.var() - a * a / 3) < 5 * math.sqrt((a**4 / 5 - a**4 / 9) / m)
    # Without drift an override is exact.
    eff0 = PulseEffect(PulseConfig(periods_ms={3: 1000}), [3], 5)
    assert eff0.periods_s[0] == 1.0


def test_seeded_reproducible_and_keyed_by_transmitter_id():
    cfg = PulseConfig(drift_ppm=100)
    a = PulseEffect(cfg, [1, 2, 3], 42)
    b = PulseEffect(cfg, [1, 2, 3], 42)
    c = PulseEffect(cfg, [1, 2, 3], 43)
    assert np.array_equal(a.periods_s, b.periods_s) and np.array_equal(a.phases_s, b.phases_s)
    assert np.array_equal(run(a, 0, 500), run(b, 0, 500))
    assert not np.any(a.periods_s == c.periods_s)
    # A transmitter's timing depends on its id only, not on which others exist.
    alone = PulseEffect(cfg, [2], 42)
    assert alone.periods_s[0] == a.periods_s[1] and alone.phases_s[0] == a.phases_s[1]
    # An override of the period leaves the drawn phase fraction and the others alone.
    over = PulseEffect(PulseConfig(drift_ppm=100, periods_ms={1: 1000}), [1, 2, 3], 42)
    assert np.array_equal(over.periods_s[1:], a.periods_s[1:])
    assert over.phases_s[0] / over.periods_s[0] == pytest.approx(a.phases_s[0] / a.periods_s[0], rel=1e-12)


# --- an isolated transmitter ----------------------------------------------------------


@pytest.mark.parametrize(
    "period_ms, rate_hz",
    [(1300, 1.0), (1000, 1.0), (700, 1.0), (1000, 2.0), (1250, 3.0), (1100, 0.5), (900, 0.25)],
)
def test_isolated_transmitter_reported_in_min_1_window_over_period_of_epochs(period_ms, rate_hz):
    # Windows tile time, so the pulses ending in K windows are the pulses ending in a
    # span K / rate: K w / P +- 1. With w < P a window holds at most one, so the number
    # of reporting epochs is that count; with w >= P every window holds one.
    k = 20_000
    for seed in (1, 2, 3):
        eff = PulseEffect(PulseConfig(periods_ms={5: period_ms}), [5], seed)
        rep = run(eff, 0, k, rate_hz)
        expected = k * min(1.0, 1000.0 / (rate_hz * period_ms))
        assert abs(rep.sum() - expected) <= 1
        assert eff.pulses_hidden == 0
        assert abs(eff.pulses_ended - k * 1000.0 / (rate_hz * period_ms)) <= 1


@pytest.mark.parametrize("periods", ["drawn", "fixed"])
def test_isolated_fraction_over_random_phases_is_window_over_period(periods):
    # One window per transmitter, random phase: P(reported) = w / P_j exactly.
    w, total, expected, var = 0.3, 0, 0.0, 0.0
    for tx_id in range(3000):
        cfg = PulseConfig() if periods == "drawn" else PulseConfig(periods_ms={tx_id: 1000})
        eff = PulseEffect(cfg, [tx_id], seed=99)
        total += int(eff.reported([100.0], [100.0 + w], [[0.0]], [[True]])[0, 0])
        p = w / eff.periods_s[0]
        expected += p
        var += p * (1 - p)
    assert abs(total - expected) < 5 * math.sqrt(var)


def test_pulse_ending_exactly_on_an_epoch_belongs_to_that_epoch():
    # phase 0.875, W 0.125: pulses end at integers n + 1.0; window (k-1, k] holds one.
    eff = PulseEffect(PulseConfig(periods_ms={1: 1000}, phases_ms={1: 875}, pulse_ms=125), [1], 0)
    rep = eff.reported([0.0, 1.0, 1.5, 2.0], [1.0, 1.5, 2.0, 2.0], np.zeros((4, 1)), np.ones((4, 1), bool))
    assert rep[:, 0].tolist() == [True, False, True, False]


def test_absent_transmitter_is_never_reported():
    eff = PulseEffect(PulseConfig(periods_ms={1: 700}), [1], 0)
    present = np.zeros((100, 1), dtype=bool)
    assert not run(eff, 0, 100, present=present).any()
    assert eff.pulses_ended == 0


# --- overlap ------------------------------------------------------------------------------

# Binary-exact timings: period 1 s, pulse 125 ms, phases multiples of 1/8 s.
SAME = dict(periods_ms={1: 1000, 2: 1000}, pulse_ms=125)


@pytest.mark.parametrize("phase2", [0, 125 - 1e-6, 125 / 2, 1000 - 124])
def test_equal_periods_overlapping_weaker_is_always_lost(phase2):
    eff = PulseEffect(PulseConfig(**SAME, phases_ms={1: 0, 2: phase2}), [1, 2], 0)
    strength = np.tile([1.0, 2.0], (400, 1))  # transmitter 2 is stronger
    rep = run(eff, 0, 400, strength=strength)
    assert rep[:, 1].all() and not rep[:, 0].any()
    assert eff.pulses_hidden == 400  # every pulse of 1


def test_equal_periods_equal_strength_higher_id_is_lost():
    eff = PulseEffect(PulseConfig(**SAME, phases_ms={1: 500, 2: 500}), [1, 2], 0)
    rep = run(eff, 0, 300)
    assert rep[:, 0].all() and not rep[:, 1].any()


@pytest.mark.parametrize("phase2", [0, 100, 875 + 1])
def test_equal_periods_overlapping_both_are_lost(phase2):
    eff = PulseEffect(PulseConfig(**SAME, phases_ms={1: 0, 2: phase2}, overlap="both"), [1, 2], 0)
    rep = run(eff, 0, 300, strength=np.tile([1.0, 2.0], (300, 1)))
    assert not rep.any()
    assert eff.pulses_hidden == eff.pulses_ended == 600


@pytest.mark.parametrize("phase2", [125, 500, 875])
def test_pulses_that_only_touch_or_are_apart_do_not_hide(phase2):
    eff = PulseEffect(PulseConfig(**SAME, phases_ms={1: 0, 2: phase2}, overlap="both"), [1, 2], 0)
    rep = run(eff, 0, 300)
    assert rep.all() and eff.pulses_hidden == 0


def test_an_absent_transmitter_hides_nothing():
    eff = PulseEffect(PulseConfig(**SAME, phases_ms={1: 0, 2: 0}, overlap="both"), [1, 2], 0)
    present = np.ones((200, 2), dtype=bool)
    present[100:, 1] = False  # transmitter 2 goes out of range half way
    rep = run(eff, 0, 200, present=present)
    assert not rep[:100].any()
    assert rep[100:, 0].all() and not rep[100:, 1].any()


BEAT_W, BEAT_P1, BEAT_P2 = 100.0, 1000.0, 1002.0  # ms; beat 1 / |1/P1 - 1/P2| = 501 s


def beat_run(overlap, k=5010):
    cfg = PulseConfig(periods_ms={1: BEAT_P1, 2: BEAT_P2}, pulse_ms=BEAT_W, overlap=overlap)
    eff = PulseEffect(cfg, [1, 2], seed=3)
    strength = np.tile([2.0, 1.0], (k, 1))  # transmitter 1 is stronger
    return eff, run(eff, 0, k, strength=strength)


def n_pulses(eff, j, k):
    """Pulses of column j ending in (-1, k - 1] (the windows of epochs 0..k-1)."""
    c = lambda t: math.floor((t - eff.phases_s[j] - eff.pulse_s) / eff.periods_s[j])  # noqa: E731
    return c(k - 1) - c(-1)


def test_beat_hidden_fraction_matches_overlap_fraction():
    # A pulse of 1 overlaps one of 2 iff its offset u in 2's pulse train lies within W of
    # a start of 2: a circular interval of length 2W out of P2. Over the run u advances by
    # |P1 - P2| per pulse and wraps L = n |P1 - P2| / P2 times; each pass lands
    # floor or ceil of 2W / |P1 - P2| pulses in the interval, so the hidden count is
    # n 2W / P2 within L + 2. Same for 2 with 2W / P1.
    k = 5010
    eff, rep = beat_run("both", k)
    n1, n2 = n_pulses(eff, 0, k), n_pulses(eff, 1, k)
    assert eff.pulses_ended == n1 + n2
    step = abs(BEAT_P1 - BEAT_P2)
    tol1 = n1 * step / BEAT_P2 + 2
    tol2 = n2 * step / BEAT_P1 + 2
    hidden1 = k - rep[:, 0].sum()  # P1 = 1 s = window: one pulse of 1 per epoch
    assert n1 == k
    assert abs(hidden1 - n1 * 2 * BEAT_W / BEAT_P2) <= tol1
    assert abs(eff.pulses_hidden - hidden1 - n2 * 2 * BEAT_W / BEAT_P1) <= tol2
    # About 2W/P = 20 % of pulses are lost: a wrong overlap window (W/P) would be 10 %.
    assert 0.19 < hidden1 / k < 0.21


def test_beat_runs_recur_at_the_beat_period():
    k = 5010
    eff, rep = beat_run("both", k)
    hidden = ~rep[:, 0]
    edges = np.flatnonzero(np.diff(hidden.astype(np.int8)))
    starts = edges[hidden[edges + 1]] + 1
    ends = edges[~hidden[edges + 1]] + 1
    beat = 1.0 / abs(1000.0 / BEAT_P1 - 1000.0 / BEAT_P2)  # seconds = epochs at 1 Hz
    assert beat == pytest.approx(501.0)
    assert len(starts) >= 9
    assert np.all(np.abs(np.diff(starts) - beat) <= 1)
    # Each run lasts 2W / |P1 - P2| = 100 pulses (+-1): the overlap, then clear again.
    runs = [e - s for s, e in zip(starts, ends[ends > starts[0]])]
    assert all(abs(r - 2 * BEAT_W / abs(BEAT_P1 - BEAT_P2)) <= 1 for r in runs)


def test_beat_weaker_only_the_weaker_loses():
    k = 5010
    eff, rep = beat_run("weaker", k)
    assert rep[:, 0].all()  # the stronger (1) is never hidden
    n2 = n_pulses(eff, 1, k)
    tol = n2 * abs(BEAT_P1 - BEAT_P2) / BEAT_P1 + 2
    assert abs(eff.pulses_hidden - n2 * 2 * BEAT_W / BEAT_P1) <= tol


# --- against the brute-force reference, and chunking ---------------------------------------


def random_inputs(rng, n, m, rate_hz):
    t_prev, t_now = windows(0, n, rate_hz)
    strength = rng.integers(0, 4, size=(n, m)).astype(float)  # ties happen
    present = rng.random((n, m)) < 0.85
    return t_prev, t_now, strength, present


@pytest.mark.parametrize("overlap", ["weaker", "both"])
@pytest.mark.parametrize("rate_hz", [1.0, 0.25, 3.0])
@pytest.mark.parametrize(
    "timing",
    [
        dict(period_ms=(700, 900), pulse_ms=250, drift_ppm=300),
        # Pulses longer than half a period: a pulse can overlap two of another's.
        dict(period_ms=(1250, 1300), pulse_ms=850),
    ],
)
def test_matches_brute_force_reference(overlap, rate_hz, timing):
    rng = np.random.default_rng(7)
    cfg = PulseConfig(**timing, overlap=overlap)
    eff = PulseEffect(cfg, [2, 4, 9, 11, 30], seed=8)
    args = random_inputs(rng, 400, 5, rate_hz)
    got = eff.reported(*args)
    want, hidden = reference(eff, *args)
    assert np.array_equal(got, want)
    assert eff.pulses_hidden == hidden
    assert hidden > 50  # the case is not trivial


def test_chunking_invariance():
    rng = np.random.default_rng(1)
    cfg = PulseConfig(pulse_ms=200, drift_ppm=50)
    ids = [1, 2, 3, 4]
    args = random_inputs(rng, 3000, 4, 1.0)
    whole = PulseEffect(cfg, ids, 5)
    expected = whole.reported(*args)
    parts = PulseEffect(cfg, ids, 5)
    out, lo = [], 0
    while lo < 3000:
        hi = min(3000, lo + int(rng.integers(1, 300)))
        out.append(parts.reported(*(a[lo:hi] for a in args)))
        lo = hi
    assert np.array_equal(np.concatenate(out), expected)
    assert parts.stats() == whole.stats()
    assert whole.pulses_hidden > 0


def test_long_times_stay_exact():
    # Days of scene time: the count function still tiles windows exactly.
    eff = PulseEffect(PulseConfig(periods_ms={1: 1300}), [1], 4)
    k0 = 86400 * 30
    rep = run(eff, k0, k0 + 13_000)
    assert abs(rep.sum() - 10_000) <= 1
