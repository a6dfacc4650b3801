"""The ``quantize`` effect: display profiles, exact integer tables worked out by hand."""

import numpy as np
import pytest

from emulator.receiver.quantize import PROFILES, QuantizeConfig, QuantizeEffect
from firmware_proto.errors import InputError


def q(cfg, d=None, delta=None, outer=None):
    if d is None:
        d = np.zeros_like(np.asarray(delta))
    if delta is None:
        delta = np.zeros_like(np.asarray(d))
    d, delta = np.asarray(d, dtype=np.int64), np.asarray(delta, dtype=np.int64)
    if outer is None:
        outer = np.zeros(d.shape, dtype=bool)
    return QuantizeEffect(cfg).apply(d, delta, outer)


ALL_DELTA = np.arange(-89, 90)


def step_table(edges_values, x):
    """Piecewise-constant expected values: [(lo, hi, value), ...] on |x|, odd in x."""
    out = np.empty_like(x)
    for lo, hi, v in edges_values:
        sel = (np.abs(x) >= lo) & (np.abs(x) <= hi)
        out[sel] = np.sign(x[sel]) * v
    return out


def test_leds5_five_values_switching_at_18_and_54_degrees():
    _, got = q(QuantizeConfig("leds5"), delta=ALL_DELTA)
    want = step_table([(0, 17, 0), (18, 53, 36), (54, 89, 72)], ALL_DELTA)
    assert got.tolist() == want.tolist()
    assert sorted(set(got.tolist())) == [-72, -36, 0, 36, 72]
    assert got[ALL_DELTA == 89][0] == 72 and got[ALL_DELTA == -89][0] == -72


def test_leds3_three_values_switching_at_30_degrees():
    _, got = q(QuantizeConfig("leds3"), delta=ALL_DELTA)
    want = step_table([(0, 29, 0), (30, 89, 60)], ALL_DELTA)
    assert got.tolist() == want.tolist()
    assert sorted(set(got.tolist())) == [-60, 0, 60]


@pytest.mark.parametrize("step", [30, 45, 90])
def test_steps_whose_multiple_passes_89_clamp_to_89(step):
    _, got = q(QuantizeConfig(delta_step_deg=step), delta=ALL_DELTA)
    assert got.min() == -89 and got.max() == 89
    assert got[ALL_DELTA == 89][0] == 89
    assert all(v % step == 0 or abs(v) == 89 for v in got.tolist())


def test_display_dm_decimetres_below_10_m_metres_above():
    d = np.array([0, 4, 5, 15, 25, 994, 995, 999, 1000, 1049, 1050, 1149, 1150, 4999, 5000])
    want = [0, 0, 10, 20, 30, 990, 1000, 1000, 1000, 1000, 1100, 1100, 1200, 5000, 5000]
    got, _ = q(QuantizeConfig("display_dm"), d=d)
    assert got.tolist() == want


def test_display_m_rounds_halves_away_from_zero_not_to_even():
    d = np.array([0, 49, 50, 149, 150, 250, 350, 2549, 2550])
    got, _ = q(QuantizeConfig("display_m"), d=d)
    assert got.tolist() == [0, 0, 100, 100, 200, 300, 400, 2500, 2600]  # banker's: 200, 400


def test_displayed_distance_is_monotone_in_true_distance():
    d = np.arange(0, 20_000)
    for cfg in (QuantizeConfig("display_dm"), QuantizeConfig(d_step_cm=25, d_far_cm=1500, d_step_far_cm=500)):
        got, _ = q(cfg, d=d)
        assert np.all(np.diff(got) >= 0)
        assert np.all(np.abs(got - d) <= np.where(d >= cfg.d_far_cm, cfg.d_step_far_cm, cfg.d_step_cm) // 2)


def test_outer_entries_stay_minus_one_and_inputs_untouched():
    d = np.array([[-1, 1234, 0], [-1, -1, 5000]])
    delta = np.array([[-1, 40, 0], [-1, -1, -89]])
    outer = d < 0
    d0, delta0 = d.copy(), delta.copy()
    cfg = QuantizeConfig("leds5", d_step_cm=100)
    got_d, got_delta = q(cfg, d, delta, outer)
    assert got_d.tolist() == [[-1, 1200, 0], [-1, -1, 5000]]
    assert got_delta.tolist() == [[-1, 36, 0], [-1, -1, -72]]
    assert got_d.dtype == np.int64 and got_delta.dtype == np.int64
    assert np.array_equal(d, d0) and np.array_equal(delta, delta0)
    assert not np.shares_memory(got_d, d) and not np.shares_memory(got_delta, delta)


def test_direction_only_profile_leaves_distance_and_vice_versa():
    rng = np.random.default_rng(0)
    d = rng.integers(0, 5001, 1000)
    delta = rng.integers(-89, 90, 1000)
    got_d, got_delta = q(QuantizeConfig("leds3"), d, delta)
    assert np.array_equal(got_d, d) and not np.array_equal(got_delta, delta)
    got_d, got_delta = q(QuantizeConfig("display_m"), d, delta)
    assert np.array_equal(got_delta, delta) and not np.array_equal(got_d, d)


def test_explicit_fields_override_the_profile():
    cfg = QuantizeConfig("display_dm", d_step_far_cm=500, d_far_cm=2000)
    assert (cfg.d_step_cm, cfg.d_far_cm, cfg.d_step_far_cm, cfg.delta_step_deg) == (10, 2000, 500, None)
    got, _ = q(cfg, d=np.array([1996, 2000, 2249, 2250]))
    assert got.tolist() == [2000, 2000, 2000, 2500]
    cfg = QuantizeConfig("leds5", delta_step_deg=10)
    _, got = q(cfg, delta=np.array([4, 5, -5, -15, 89]))
    assert got.tolist() == [0, 10, -10, -20, 89]
    assert set(PROFILES) == {"leds5", "leds3", "display_dm", "display_m"}


def test_random_values_against_integer_arithmetic():
    # Independent formulation: nearest multiple with halves away from zero, in integers.
    rng = np.random.default_rng(3)
    delta = rng.integers(-89, 90, 20_000)
    d = rng.integers(0, 10**7, 20_000)
    for step in range(1, 91):
        _, got = q(QuantizeConfig(delta_step_deg=step), delta=delta)
        want = np.sign(delta) * ((2 * np.abs(delta) + step) // (2 * step)) * step
        assert np.array_equal(got, np.clip(want, -89, 89)), step
    for step in (1, 7, 10, 100, 333):
        got, _ = q(QuantizeConfig(d_step_cm=step), d=d)
        assert np.array_equal(got, (2 * d + step) // (2 * step) * step), step


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"profile": "leds7"}, "quantize.profile: must be one of leds5, leds3, display_dm, display_m, got 'leds7'"),
        ({}, "quantize.profile: give a profile (leds5, leds3, display_dm, display_m) or at least one step"),
        ({"delta_step_deg": 0}, "quantize.delta_step_deg: must be >= 1, got 0"),
        ({"delta_step_deg": 91}, "quantize.delta_step_deg: must be <= 90, got 91"),
        ({"delta_step_deg": 2.5}, "quantize.delta_step_deg: must be a whole number, got 2.5"),
        ({"d_step_cm": True}, "quantize.d_step_cm: must be a whole number, got True"),
        ({"d_step_cm": -10}, "quantize.d_step_cm: must be >= 1, got -10"),
        ({"d_far_cm": 1000}, "quantize.d_step_far_cm: d_far_cm and d_step_far_cm go together, d_step_far_cm is missing"),
        ({"d_step_far_cm": 100}, "quantize.d_far_cm: d_far_cm and d_step_far_cm go together, d_far_cm is missing"),
        (
            {"d_step_cm": 10, "d_far_cm": 1020, "d_step_far_cm": 100},
            "quantize.d_far_cm: must be a multiple of d_step_cm (10) and d_step_far_cm (100) so displayed "
            "distances stay monotone, got 1020",
        ),
    ],
)
def test_config_rejects(kwargs, message):
    with pytest.raises(InputError) as err:
        QuantizeConfig(**kwargs)
    assert str(err.value) == message


def test_whole_float_steps_are_accepted_and_shapes_checked():
    assert QuantizeConfig(delta_step_deg=36.0).delta_step_deg == 36
    with pytest.raises(InputError, match="one shape"):
        QuantizeEffect(QuantizeConfig("leds5")).apply(np.zeros(3), np.zeros(3), np.zeros(2, bool))
