"""Receiver classes in the model: the 2-antenna receiver (dxy in every zone) next to the
3-antenna default (docs/model.md, "Receiver classes"); hard cases and invariances."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import model_properties as props
import reference_model as ref
from emulator.receiver.model import ZONE_INNER, ZONE_OUTER, ModelParams, measure, measure_one
from emulator.receiver.noise import NoiseEffect
from firmware_proto.errors import InputError, PoseError

I = (1.0, 0.0, 0.0, 0.0)
ORIGIN = (0.0, 0.0, 0.0)
PERM = (0.5, 0.5, 0.5, 0.5)  # body z = world x exactly (see test_model.py)
#: A transmitter whose dipole points straight up: -90 degrees about y takes x to z.
VERTICAL = (math.sqrt(0.5), 0.0, -math.sqrt(0.5), 0.0)
TWO = ModelParams(antennas=2)
THREE = ModelParams(antennas=3)


def scan(depth_m, params, half_width_cm=150):
    """(x in cm, d, delta, zone) along y = 0 on the surface z = 0, 1 cm apart, over a
    vertical transmitter buried ``depth_m`` below (0, 0)."""
    x_cm = np.arange(-half_width_cm, half_width_cm + 1)
    rx = np.c_[x_cm / 100.0, np.zeros(x_cm.size), np.zeros(x_cm.size)]
    m = measure(rx, np.tile(I, (x_cm.size, 1)), [(0.0, 0.0, -depth_m)], [VERTICAL], params)
    return x_cm, m.d[:, 0], m.delta[:, 0], m.zone[:, 0]


def signal_maximum(x_cm, d):
    """Where d is smallest (the strongest signal), outer entries (-1) excluded."""
    dd = np.where(d < 0, np.iinfo(np.int64).max, d)
    return int(dd.min()), x_cm[dd == dd.min()].tolist()


class TestVerticalTransmitterScan:
    """h_xy = 3 D rho / r^5 is largest at rho = D / 2, |h| at rho = 0."""

    def test_two_antennas_peak_half_the_depth_off_the_victim(self):
        x_cm, d, delta, zone = scan(2.0, TWO)
        d_min, where = signal_maximum(x_cm, d)
        # dxy at rho = D/2 = 1 m: r = sqrt(5), |u_xy| = 6/5: 100 sqrt(5) cbrt(1.542 / 1.2) = 243.1
        assert d_min == 243
        assert where == list(range(-108, -92)) + list(range(93, 109))  # plateau around +-100 cm
        # The spike: right above the victim the horizontal antennas hear nothing.
        assert (int(d[150]), int(delta[150]), int(zone[150])) == (-1, -1, ZONE_OUTER)
        assert d[140:161].tolist() == [436, 451, 469, 490, 516, 548, 590, 650, 744, 937, -1,
                                       937, 744, 650, 590, 548, 516, 490, 469, 451, 436]  # fmt: skip

    def test_three_antennas_peak_above_the_victim(self):
        x_cm, d, delta, zone = scan(2.0, THREE)
        d_min, where = signal_maximum(x_cm, d)
        assert d_min == 183  # 100 * 2 * cbrt(1.542 / 2) on the axis
        assert where == list(range(-6, 7))
        assert (int(d[150]), int(delta[150]), int(zone[150])) == (183, 0, ZONE_INNER)

    def test_one_metre_burial(self):
        x_cm, d, _, _ = scan(1.0, TWO, 100)
        assert signal_maximum(x_cm, d) == (122, list(range(-58, -41)) + list(range(42, 59)))
        x_cm, d, _, _ = scan(1.0, THREE, 100)
        assert signal_maximum(x_cm, d) == (92, list(range(-11, 12)))

    def test_beyond_the_third_antennas_range_both_classes_agree(self):
        # 4 m deep: d3 above the victim is 367 cm > r_inner, so the 3-antenna unit is in
        # its mid zone there and behaves like the 2-antenna one (Ayuso's "within the
        # third antenna's range").
        x2, d2, _, _ = scan(4.0, TWO, 300)
        x3, d3, _, _ = scan(4.0, THREE, 300)
        assert d2.tolist() == d3.tolist()
        assert signal_maximum(x2, d2) == (486, list(range(-209, -190)) + list(range(191, 210)))


class TestTwoAntennaHardCases:
    def test_receiver_at_transmitter_is_inner_zero(self):
        assert measure_one(ORIGIN, I, ORIGIN, params=TWO) == (0, 0)
        assert measure_one((1e-200, 0, 0), I, ORIGIN, params=TWO) == (0, 0)
        assert measure_one((5e-324, 0, 0), I, ORIGIN, params=TWO) == (0, 0)

    def test_far_is_outer(self):
        assert measure_one((1e200, 0, 0), I, ORIGIN, params=TWO) == (-1, -1)
        assert measure_one((-1e308, 1e308, 1e308), PERM, (1e308, -1e308, 0), params=TWO) == (-1, -1)

    def test_hxy_zero_is_outer_even_close(self):
        # The 3-antenna unit reads 183 cm here from its third antenna; the 2-antenna unit nothing.
        assert measure_one((2, 0, 0), PERM, ORIGIN, params=THREE) == (183, 0)
        assert measure_one((2, 0, 0), PERM, ORIGIN, params=TWO) == (-1, -1)
        assert measure_one((1e-100, 0, 0), PERM, ORIGIN, params=TWO) == (-1, -1)

    def test_inner_zone_from_dxy(self):
        # Receiver tilted 60 degrees about y on the axis 2 m away: |u| = 2, |u_xy| = 1.
        t = (math.cos(math.radians(30)), 0.0, math.sin(math.radians(30)), 0.0)
        assert measure_one((2, 0, 0), t, ORIGIN, params=THREE) == (183, 0)  # d3 = 2 cbrt(1.542/2)
        assert measure_one((2, 0, 0), t, ORIGIN, params=TWO) == (231, 0)  # dxy = 2 cbrt(1.542)

    def test_either_side_of_300_and_5000_cm(self):
        b = 3.0 / math.cbrt(1.542)
        q = (math.cos(math.radians(15)), 0.0, 0.0, math.sin(math.radians(15)))
        assert measure_one((0, b * (1 - 1e-9), 0), q, ORIGIN, params=TWO) == (300, 0)
        assert measure_one((0, b * (1 + 1e-9), 0), q, ORIGIN, params=TWO) == (300, -30)
        b = 50.0 / math.cbrt(1.542)
        assert measure_one((0, b * (1 - 1e-9), 0), I, ORIGIN, params=TWO) == (5000, 0)
        assert measure_one((0, b * (1 + 1e-9), 0), I, ORIGIN, params=TWO) == (-1, -1)

    def test_noise_on_overflowing_field_stays_finite(self):
        w = NoiseEffect(seed=3).draw(4, 1)
        rx = [(0, 0, 0), (1e-200, 0, 0), (1e200, 0, 0), (0, 0, 1e-320)]
        m = measure(rx, [I] * 4, [ORIGIN], [I], TWO, noise=w, want_field=True)
        assert m.d[:2, 0].tolist() == [0, 0] and m.delta[:2, 0].tolist() == [0, 0]
        assert np.all(np.isfinite(m.field))
        assert m.zone[2, 0] != ZONE_INNER
        # Straight above a dipole lying along x the field is horizontal: 2 antennas hear it.
        assert m.zone[3, 0] == ZONE_INNER and m.d[3, 0] == 0

    def test_field_has_no_z_component_with_two_antennas(self):
        rx = [(2.0, 1.0, 0.5), (0.0, 0.0, 3.0)]
        m2 = measure(rx, [I, I], [ORIGIN], [VERTICAL], TWO, want_field=True)
        m3 = measure(rx, [I, I], [ORIGIN], [VERTICAL], THREE, want_field=True)
        assert m2.field[..., :2].tolist() == m3.field[..., :2].tolist()
        assert m2.field[..., 2].tolist() == [[0.0], [0.0]] and m3.field[1, 0, 2] > 0

    def test_default_is_three_antennas(self):
        assert ModelParams() == THREE
        assert ModelParams().antennas == 3

    @pytest.mark.parametrize("bad", [1, 4, 0, True, 2.5, "2"])
    def test_antennas_validated(self, bad):
        with pytest.raises(InputError, match=r"^receiver.antennas: must be 2 or 3, got "):
            ModelParams(antennas=bad)


# --------------------------------------------------------------------------- invariances
coord = st.floats(-60, 60, allow_nan=False)
vec = st.tuples(coord, coord, coord)
quat = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: sum(c * c for c in q) > 1e-4)
PROPERTY = settings(max_examples=150, deadline=None)


def _near_boundary(rx_p, rx_q, tx_p, tx_q):
    """A hair from a rounding or zone boundary of dxy or delta (BRIEF 3)."""
    _, dxy, delta = ref.raw(rx_p, rx_q, tx_p, tx_q)
    near = lambda v, eps=1e-6: abs(v - round(v)) < eps  # noqa: E731
    half = lambda v: near(v - 0.5) if v >= 0 else near(v + 0.5)  # noqa: E731
    if math.isfinite(dxy) and (abs(dxy - 3.0) < 1e-7 or abs(dxy - 50.0) < 1e-7 or half(100 * dxy)):
        return True
    if not math.isfinite(dxy) or dxy < 1e-6:
        return True  # h_xy is a rounding residue: zero or not is not determined
    return ref.delta_near_boundary(delta)


def _separated(a, b):
    return math.dist(a, b) > 0.05


@PROPERTY
@given(rx_p=vec, rx_q=quat, tx_p=vec, tx_q=quat)
def test_matches_plain_transcription(rx_p, rx_q, tx_p, tx_q):
    assume(_separated(rx_p, tx_p) and not _near_boundary(rx_p, rx_q, tx_p, tx_q))
    assert measure_one(rx_p, rx_q, tx_p, tx_q, TWO) == ref.measure(rx_p, rx_q, tx_p, tx_q, antennas=2)


@PROPERTY
@given(rx_p=vec, rx_q=quat, tx_p=vec, tx_q=quat, g=quat)
def test_rotating_both_devices_together_changes_nothing(rx_p, rx_q, tx_p, tx_q, g):
    assume(_separated(rx_p, tx_p) and not _near_boundary(rx_p, rx_q, tx_p, tx_q))
    from scipy.spatial.transform import Rotation

    G = Rotation.from_quat(g, scalar_first=True)
    rot_q = lambda q: (G * Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)  # noqa: E731
    before = measure_one(rx_p, rx_q, tx_p, tx_q, TWO)
    after = measure_one(G.apply(rx_p), rot_q(rx_q), G.apply(tx_p), rot_q(tx_q), TWO)
    assert after == before


@PROPERTY
@given(p=vec, rx_q=quat, tx_q=quat)
def test_even_in_p(p, rx_q, tx_q):
    assume(math.hypot(*p) > 1e-3)
    m = measure([p, tuple(-c for c in p)], [rx_q, rx_q], [ORIGIN], [tx_q], TWO)
    assert m.d[0, 0] == m.d[1, 0] and m.delta[0, 0] == m.delta[1, 0]


@PROPERTY
@given(direction=vec, rx_q=quat, tx_q=quat)
def test_d_is_monotone_along_a_ray(direction, rx_q, tx_q):
    assume(math.hypot(*direction) > 1e-3)
    props.assert_d_monotone_along_a_ray(direction, rx_q, tx_q, TWO)


@PROPERTY
@given(rx_p=vec, rx_q=quat, tx_p=vec, tx_q=quat)
def test_two_antennas_never_read_closer_than_three(rx_p, rx_q, tx_p, tx_q):
    """|h_xy| <= |h|, so dxy >= d3: where both units read, the 2-antenna d is not smaller."""
    m2 = measure([rx_p], [rx_q], [tx_p], [tx_q], TWO)
    m3 = measure([rx_p], [rx_q], [tx_p], [tx_q], THREE)
    if m2.zone[0, 0] != ZONE_OUTER:
        assert m3.zone[0, 0] != ZONE_OUTER and m2.d[0, 0] >= m3.d[0, 0]


finite = st.floats(allow_nan=False, allow_infinity=False)


@PROPERTY
@given(
    rx_p=st.tuples(finite, finite, finite),
    rx_q=st.tuples(finite, finite, finite, finite),
    tx_p=st.tuples(finite, finite, finite),
    tx_q=st.tuples(finite, finite, finite, finite),
    noise=st.booleans(),
    seed=st.integers(0, 2**32),
)
def test_any_finite_input_gives_in_range_integers(rx_p, rx_q, tx_p, tx_q, noise, seed):
    w = NoiseEffect(seed).draw(1, 1) if noise else None
    try:
        m = measure([rx_p], [rx_q], [tx_p], [tx_q], TWO, noise=w, want_field=True)
    except PoseError as exc:
        assert exc.field in ("receiver.orientation", "transmitter.orientation")
        return
    props.assert_one_reading_in_range(m)
