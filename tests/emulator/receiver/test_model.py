"""The receiver model (BRIEF 2-3): golden integers, every hard case of 3.3, invariances."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import model_properties as props
import reference_model as ref
from emulator.receiver.noise import NoiseEffect
from emulator.receiver.model import (
    ZONE_INNER,
    ModelParams,
    measure,
    measure_one,
    round_half_away,
    select_channels,
)
from firmware_proto.errors import InputError, PoseError

I = (1.0, 0.0, 0.0, 0.0)
ORIGIN = (0.0, 0.0, 0.0)
#: 120 degrees about (1,1,1): an exactly representable rotation; body z = world x,
#: body x = world y, body y = world z, so receiver-frame zeros are exact zeros.
PERM = (0.5, 0.5, 0.5, 0.5)
C45 = math.sqrt(0.5)
PAPER_TX = {1: (20, 5, 0), 2: (10, 0, 1), 3: (20, -20, -1), 4: (-6, 5, 0)}


def yaw(deg):
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def paper(rx_p, rx_q):
    ids = np.array(sorted(PAPER_TX))
    m = measure([rx_p], [rx_q], [PAPER_TX[i] for i in ids], [I] * 4)
    return {int(i): (int(m.d[0, j]), int(m.delta[0, j])) for j, i in enumerate(ids)}


# Golden values: worked out from the brief's formulas by hand/with a plain transcription,
# not with the code under test.
@pytest.mark.parametrize(
    "rx_p, rx_q, expected",
    [
        (ORIGIN, I, {1: (1905, 21), 2: (926, 0), 3: (2808, -72), 4: (761, -62)}),
        ((10, 0, 0), I, {1: (1053, 41), 2: (116, 0), 3: (2392, 71), 4: (1555, -26)}),
        ((5, 5, 2), yaw(30), {1: (1400, -30), 2: (714, 78), 3: (3081, 51), 4: (1042, -30)}),
        ((18, 4, 0), I, {1: (211, 0), 2: (853, 41), 3: (2775, 14), 4: (2203, -4)}),
        ((-30, -20, 1.5), (0.9, 0.1, -0.2, 0.3), {1: (-1, -1), 2: (4384, 3), 3: (4714, -42), 4: (3582, 40)}),
        ((-60, 0, 0), I, {1: (-1, -1), 2: (-1, -1), 3: (-1, -1), 4: (4978, 8)}),
    ],
)
def test_golden_paper_scene(rx_p, rx_q, expected):
    assert paper(rx_p, rx_q) == expected


def test_axis_and_broadside_factors():
    # 0.917 r on the dipole axis, 1.155 r broadside (BRIEF 3 step 4).
    assert measure_one((10, 0, 0), I, ORIGIN) == (917, 0)
    assert measure_one((0, 10, 0), I, ORIGIN) == (1155, 0)
    assert measure_one((0, 0, -10), I, ORIGIN) == (1155, 0)


def test_yawed_receiver_on_axis_is_917_not_no_signal():
    # arva_sim swaps rotation roles and reports nothing here (BRIEF appendix B.1).
    # h_x is a rounding residue of cos(90 deg) here, so the side of the +-90 fold (the
    # sign of delta) is not determined; exact zeros are tested with PERM below.
    d, delta = measure_one((10, 0, 0), (C45, 0, 0, C45), ORIGIN)
    assert (d, abs(delta)) == (917, 89)
    d, delta = measure_one((0, 10, 0), I, ORIGIN, (C45, 0, 0, C45))
    assert (d, abs(delta)) == (917, 89)


class TestHardCases:
    def test_receiver_at_transmitter(self):
        assert measure_one(ORIGIN, I, ORIGIN) == (0, 0)
        assert measure_one((3.5, -2, 1e7), PERM, (3.5, -2, 1e7), yaw(33)) == (0, 0)

    def test_r_1e_minus_200_is_inner_zero(self):
        assert measure_one((1e-200, 0, 0), I, ORIGIN) == (0, 0)
        assert measure_one((1e-200, 1e-200, 1e-200), yaw(10), ORIGIN) == (0, 0)
        assert measure_one((5e-324, 0, 0), I, ORIGIN) == (0, 0)

    def test_r_1e_plus_200_is_outer(self):
        assert measure_one((1e200, 0, 0), I, ORIGIN) == (-1, -1)
        assert measure_one((-1e308, 1e308, 1e308), PERM, (1e308, -1e308, 0)) == (-1, -1)

    def test_hxy_exactly_zero_with_hz(self):
        # Field along world x = receiver z exactly: mid zone impossible -> outer.
        assert measure_one((10, 0, 0), PERM, ORIGIN) == (-1, -1)
        # ... but inside 3 m the third antenna gives d: 100 * 2 * cbrt(1.542 / 2) = 183.39.
        assert measure_one((2, 0, 0), PERM, ORIGIN) == (183, 0)

    def test_hx_exactly_zero_clamps_to_89(self):
        # h_r = (0, 3xz, 2x^2 - z^2) scaled: delta = +-90 -> clamped to +-89.
        assert measure_one((10, 0, 10), PERM, ORIGIN) == (1427, 89)
        assert measure_one((10, 0, -10), PERM, ORIGIN) == (1427, -89)

    def test_null_cone_component_cancels(self):
        # 2x^2 = y^2 + z^2: the x component of the field vanishes (cone of 54.7 deg).
        y = math.sqrt(2.0) * 10
        d, delta = measure_one((10, y, 0), I, ORIGIN)
        # d = r * cbrt(kappa / |u_y|) with |u_y| = 3 x y / r^2 = sqrt(2): 1783 cm; h_x
        # is a rounding residue, so only |delta| is determined.
        assert (d, abs(delta)) == (1783, 89)

    def test_either_side_of_300_cm(self):
        b = 3.0 / math.cbrt(1.542)
        q = yaw(30)
        assert measure_one((0, b * (1 - 1e-9), 0), q, ORIGIN) == (300, 0)  # inner
        assert measure_one((0, b * (1 + 1e-9), 0), q, ORIGIN) == (300, -30)  # mid

    def test_either_side_of_5000_cm(self):
        b = 50.0 / math.cbrt(1.542)
        assert measure_one((0, b * (1 - 1e-9), 0), I, ORIGIN) == (5000, 0)
        assert measure_one((0, b * (1 + 1e-9), 0), I, ORIGIN) == (-1, -1)

    def test_d_rounding_points(self):
        b = 12.345 / math.cbrt(1.542)  # dxy = 12.345 m -> 1234.5 cm
        assert measure_one((0, b * (1 - 1e-9), 0), I, ORIGIN) == (1234, 0)
        assert measure_one((0, b * (1 + 1e-9), 0), I, ORIGIN) == (1235, 0)

    def test_delta_rounding_points_half_away_from_zero(self):
        assert measure_one((0, 20, 0), yaw(30.5 - 1e-7), ORIGIN) == (2311, -30)
        assert measure_one((0, 20, 0), yaw(30.5 + 1e-7), ORIGIN) == (2311, -31)
        assert measure_one((0, 20, 0), yaw(-30.5 + 1e-7), ORIGIN) == (2311, 30)
        assert measure_one((0, 20, 0), yaw(-30.5 - 1e-7), ORIGIN) == (2311, 31)

    def test_round_half_away_exact(self):
        x = np.array([0.5, 1.5, 2.5, -0.5, -2.5, 0.49999999999999994, -0.49999999999999994, 1234.5, -0.0])
        assert round_half_away(x).tolist() == [1, 2, 3, -1, -3, 0, 0, 1235, 0]

    def test_unnormalised_quaternions(self):
        assert measure_one((10, 0, 0), (2, 0, 0, 0), ORIGIN) == (917, 0)
        assert measure_one((10, 0, 0), (1e200, 0, 0, 1e200), ORIGIN) == (917, -89)
        assert measure_one((10, 0, 0), (1e-8, 0, 0, 1e-8), ORIGIN) == (917, -89)
        assert measure_one((0, 20, 0), tuple(3.7 * c for c in yaw(30.5 + 1e-7)), ORIGIN) == (2311, -31)

    def test_degenerate_quaternions_name_the_field(self):
        with pytest.raises(PoseError, match=r"^receiver.orientation: quaternion norm 1e-10 is below 1e-09$"):
            measure_one((10, 0, 0), (1e-10, 0, 0, 0), ORIGIN)
        with pytest.raises(PoseError, match=r"^transmitter.orientation: quaternion norm 0 is below 1e-09$"):
            measure_one((10, 0, 0), I, ORIGIN, (0, 0, 0, 0))
        with pytest.raises(PoseError, match=r"^receiver.orientation: quaternion has a non-finite component$"):
            measure_one((10, 0, 0), (math.nan, 0, 0, 1), ORIGIN)
        with pytest.raises(PoseError, match=r"^receiver.position: position has a non-finite component$"):
            measure_one((math.inf, 0, 0), I, ORIGIN)
        assert isinstance(PoseError("x", "y"), ValueError)

    def test_float32_inputs(self):
        p32 = np.array([[5, 5, 2]], dtype=np.float32)
        q32 = np.array([[C45, 0, 0, C45]], dtype=np.float32)
        tx32 = np.array([PAPER_TX[i] for i in (1, 2, 3, 4)], dtype=np.float32)
        m32 = measure(p32, q32, tx32, np.array([I] * 4, dtype=np.float32))
        m64 = measure(p32.astype(np.float64), q32.astype(np.float64), tx32.astype(np.float64), [I] * 4)
        assert m32.d.dtype == np.int64
        assert m32.d.tolist() == m64.d.tolist() == [[1400, 714, 3081, 1042]]
        assert m32.delta.tolist() == m64.delta.tolist()

    def test_huge_coordinates_small_separation(self):
        assert measure_one((1e7 + 10, 1e7, 5), I, (1e7, 1e7, 5)) == (917, 0)
        assert measure_one((-1e7, 1e7 + 10, 3e3), I, (-1e7, 1e7, 3e3)) == (1155, 0)

    def test_noise_on_overflowing_field_stays_finite(self):
        params = ModelParams()
        w = NoiseEffect(seed=3).draw(4, 1)
        rx = [(0, 0, 0), (1e-200, 0, 0), (1e200, 0, 0), (0, 0, 1e-320)]
        m = measure(rx, [I] * 4, [ORIGIN], [I], params, noise=w, want_field=True)
        assert m.d[:2, 0].tolist() == [0, 0]  # at and next to the transmitter: inner, 0 cm
        assert m.delta[:2, 0].tolist() == [0, 0]
        assert np.all(np.isfinite(m.field))
        # 1e200 m away only the noise is heard; it is at most w_en, i.e. >= the distance
        # a field of w_en maps to, so never inner.
        assert m.zone[2, 0] != ZONE_INNER
        assert m.zone[3, 0] == ZONE_INNER and m.d[3, 0] == 0


def test_field_values_match_plain_formula():
    m = measure([(3, -4, 2)], [yaw(20)], [(1, 1, 0)], [PERM], want_field=True)
    expected = ref.field((3, -4, 2), yaw(20), (1, 1, 0), PERM)
    np.testing.assert_allclose(m.field[0, 0], expected, rtol=1e-13, atol=0)


def test_field_saturates_instead_of_inf():
    m = measure([(1e-200, 1e-200, 0)], [I], [ORIGIN], [I], want_field=True)
    assert np.all(np.isfinite(m.field))
    assert m.field[0, 0, 0] == 0.0 or abs(m.field[0, 0, 0]) == np.finfo(float).max


def test_params_validation():
    with pytest.raises(InputError, match=r"^model.kappa_eq: must be a finite number > 0, got -1$"):
        ModelParams(kappa_eq=-1)
    with pytest.raises(InputError, match=r"^model.q: must be 3 numbers in \(0, 1\], got \[1.0, 0.0, 1.0\]$"):
        ModelParams(q=(1.0, 0.0, 1.0))


class TestChannels:
    def test_sorted_by_d_then_id_and_padded(self):
        meas = measure([ORIGIN, (-60, 0, 0)], [I, I], [PAPER_TX[i] for i in (1, 2, 3, 4)], [I] * 4)
        ep = select_channels(meas, [1, 2, 3, 4], 6)
        assert ep.ids.tolist() == [[4, 2, 1, 3, -1, -1], [4, -1, -1, -1, -1, -1]]
        assert ep.d.tolist() == [[761, 926, 1905, 2808, -1, -1], [4978, -1, -1, -1, -1, -1]]
        assert ep.delta.tolist() == [[-62, 0, 21, -72, -1, -1], [8, -1, -1, -1, -1, -1]]

    def test_ties_broken_by_id(self):
        # Two transmitters mirrored about the receiver: equal d, lower id first.
        meas = measure([ORIGIN], [I], [(10, 0, 0), (-10, 0, 0), (0, 10, 0)], [I] * 3)
        assert select_channels(meas, [5, 7, 9], 2).ids.tolist() == [[5, 7]]

    def test_fewer_channels_than_transmitters(self):
        meas = measure([ORIGIN], [I], [PAPER_TX[i] for i in (1, 2, 3, 4)], [I] * 4)
        ep = select_channels(meas, [1, 2, 3, 4], 1)
        assert (ep.ids.tolist(), ep.d.tolist(), ep.delta.tolist()) == ([[4]], [[761]], [[-62]])


def test_batch_matches_scalar_calls():
    rng = np.random.default_rng(1)
    rx = rng.uniform(-70, 70, (200, 3))
    rq = rng.normal(size=(200, 4))
    tx = rng.uniform(-30, 30, (5, 3))
    tq = rng.normal(size=(5, 4))
    m = measure(rx, rq, tx, tq)
    for i in range(0, 200, 17):
        for j in range(5):
            assert (m.d[i, j], m.delta[i, j]) == measure_one(rx[i], rq[i], tx[j], tq[j])


def test_moving_transmitters_broadcast():
    tx = np.array([[[20, 5, 0]], [[10, 0, 1]]], dtype=float)  # (N=2, M=1, 3)
    m = measure([ORIGIN, ORIGIN], [I, I], tx, [I])
    assert m.d.tolist() == [[1905], [926]]


# ---------------------------------------------------------------- properties
coord = st.floats(-100, 100, allow_nan=False)
vec = st.tuples(coord, coord, coord)
quat = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: sum(c * c for c in q) > 1e-4)


def _near_boundary(rx_p, rx_q, tx_p, tx_q):
    """True if any output is within a hair of a rounding or zone boundary, where two
    correct float computations may legitimately disagree (BRIEF 3)."""
    d3, dxy, delta = ref.raw(rx_p, rx_q, tx_p, tx_q)
    near = lambda v, eps=1e-6: abs(v - round(v)) < eps  # noqa: E731
    half = lambda v: near(v - 0.5) if v >= 0 else near(v + 0.5)  # noqa: E731
    if abs(d3 - 3.0) < 1e-7 or half(100 * d3):
        return True
    if math.isfinite(dxy) and (abs(dxy - 50.0) < 1e-7 or half(100 * dxy)):
        return True
    return ref.delta_near_boundary(delta)


def _separated(a, b):
    return math.dist(a, b) > 0.05


@given(rx_p=vec, rx_q=quat, tx_p=vec, tx_q=quat)
def test_matches_plain_transcription(rx_p, rx_q, tx_p, tx_q):
    assume(_separated(rx_p, tx_p) and not _near_boundary(rx_p, rx_q, tx_p, tx_q))
    assert measure_one(rx_p, rx_q, tx_p, tx_q) == ref.measure(rx_p, rx_q, tx_p, tx_q)


@given(rx_p=vec, rx_q=quat, tx_p=vec, tx_q=quat, g=quat)
def test_rotating_both_devices_together_changes_nothing(rx_p, rx_q, tx_p, tx_q, g):
    assume(_separated(rx_p, tx_p) and not _near_boundary(rx_p, rx_q, tx_p, tx_q))
    from scipy.spatial.transform import Rotation

    G = Rotation.from_quat(g, scalar_first=True)
    rot_q = lambda q: (G * Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)  # noqa: E731
    before = measure_one(rx_p, rx_q, tx_p, tx_q)
    after = measure_one(G.apply(rx_p), rot_q(rx_q), G.apply(tx_p), rot_q(tx_q))
    assert after == before


@given(p=vec, tx_q=quat)
def test_field_is_even_in_p(p, tx_q):
    assume(math.hypot(*p) > 1e-3)
    m = measure([p, tuple(-c for c in p)], [I, I], [ORIGIN], [tx_q], want_field=True)
    np.testing.assert_allclose(m.field[0, 0], m.field[1, 0], rtol=1e-12, atol=1e-300)


@given(p=vec, rx_q=quat, lam=st.floats(1e-3, 1e3))
def test_field_magnitude_scales_as_r_minus_3(p, rx_q, lam):
    assume(math.hypot(*p) > 1e-3)
    m = measure([p, tuple(lam * c for c in p)], [rx_q, rx_q], [ORIGIN], [I], want_field=True)
    h1, h2 = np.linalg.norm(m.field[0, 0]), np.linalg.norm(m.field[1, 0])
    assert h2 == pytest.approx(h1 * lam**-3, rel=1e-12)


@given(direction=vec, rx_q=quat, tx_q=quat)
def test_d_is_monotone_along_a_ray(direction, rx_q, tx_q):
    assume(math.hypot(*direction) > 1e-3)
    props.assert_d_monotone_along_a_ray(direction, rx_q, tx_q)


finite = st.floats(allow_nan=False, allow_infinity=False)
any_quat = st.tuples(finite, finite, finite, finite)


@given(
    rx_p=st.tuples(finite, finite, finite),
    rx_q=any_quat,
    tx_p=st.tuples(finite, finite, finite),
    tx_q=any_quat,
    noise=st.booleans(),
    seed=st.integers(0, 2**32),
)
def test_any_finite_input_gives_in_range_integers(rx_p, rx_q, tx_p, tx_q, noise, seed):
    w = NoiseEffect(seed).draw(1, 1) if noise else None
    try:
        m = measure([rx_p], [rx_q], [tx_p], [tx_q], noise=w, want_field=True)
    except PoseError as exc:
        assert exc.field in ("receiver.orientation", "transmitter.orientation")
        assert "below 1e-09" in exc.reason
        return
    props.assert_one_reading_in_range(m)
