"""The batch model's fast path (issue 20) against its general path.

``measure`` takes a fast path for the ideal 3-antenna receiver with static transmitters
and no field (emulator/receiver/model/fast.py); asking for the field takes the
general path (the formulation every golden test was written against) on the same pairs.
BRIEF 3 lets two correct implementations disagree within ~1e-9 of a rounding or zone
boundary; the fast path hands such pairs to the general path, so here the integers must
be equal for every pair: millions of seeded random pairs, hairs from each boundary, exact
zeros of h_x, and the pairs it leaves to the general path (r = 0, tiny or huge r,
coordinates much larger than the separation, extreme quaternion norms), whatever block
they share.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import model_properties as props
from emulator.receiver import model
from emulator.receiver.model import ModelParams, measure
from firmware_proto.errors import InputError, PoseError

PARAMS = ModelParams()
REL = 1e-9


def _near_boundary(field, params: ModelParams) -> np.ndarray:
    """Pairs whose general-path values lie within REL (relative) of a rounding or zone
    boundary: d3 or dxy at r_inner / r_outer, 100 d at x.5, delta at x.5 or +-89.5, or
    atan's fold at +-90 (h_x a nonzero rounding residue: its sign, so delta's, is noise;
    tests/emulator/receiver/test_model.py::test_null_cone_component_cancels)."""
    def near(v, b):
        return np.abs(v - b) <= REL * np.maximum(np.abs(b), 1.0)

    def near_half(v):
        return near(v, np.floor(v) + 0.5) | near(v, np.floor(v) - 0.5) | near(v, np.ceil(v) - 0.5)

    h = np.abs(field)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        kappa = params.kappa_eq / (4.0 * math.pi)
        d3 = np.cbrt(kappa / np.sqrt(h[..., 0] ** 2 + h[..., 1] ** 2 + h[..., 2] ** 2))
        dxy = np.cbrt(kappa / np.hypot(h[..., 0], h[..., 1]))
        delta = np.nan_to_num(np.degrees(np.arctan(field[..., 1] / field[..., 0])))
        return (near(d3, params.r_inner) | near(dxy, params.r_outer) | near_half(100 * d3) | near_half(100 * dxy)
                | near_half(delta) | near(np.abs(delta), 89.5)
                | ((h[..., 0] != 0) & (h[..., 0] <= REL * h[..., 1])))


def _compare(rx_p, rx_q, tx_p, tx_q, params=PARAMS):
    """The fast path's integers equal the general path's, pair for pair.

    Pairs within ~1e-8 of a boundary (where two correct implementations may disagree,
    see _near_boundary) are handed to the general path by the fast path itself, so no
    difference is allowed at all; there must be such pairs in large samples, though.
    """
    fast = measure(rx_p, rx_q, tx_p, tx_q, params)
    general = measure(rx_p, rx_q, tx_p, tx_q, params, want_field=True)
    differ = (fast.d != general.d) | (fast.delta != general.delta) | (fast.zone != general.zone)
    assert not differ.any(), (
        f"{int(differ.sum())} pairs differ (near a boundary: {int((differ & _near_boundary(general.field, params)).sum())}),"
        f" e.g. fast {fast.d[differ][:3]} {fast.delta[differ][:3]} vs general {general.d[differ][:3]} {general.delta[differ][:3]}"
    )
    return fast, general


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_path_matches_general_path_on_a_million_random_pairs(seed):
    rng = np.random.default_rng(seed)
    n, m = 250_000, 4
    rx_p = rng.uniform(-60, 60, (n, 3))
    rx_q = rng.normal(size=(n, 4)) * rng.uniform(1e-3, 1e3, (n, 1))  # unnormalised
    tx_p = rng.uniform(-20, 20, (m, 3))
    tx_q = rng.normal(size=(m, 4))
    _compare(rx_p, rx_q, tx_p, tx_q)


def test_fast_path_matches_near_the_transmitters_and_far_away():
    rng = np.random.default_rng(2)
    tx_p = rng.uniform(-5, 5, (6, 3))
    tx_q = rng.normal(size=(6, 4))
    near = rng.uniform(-4, 4, (150_000, 3))  # inner and mid zones, null cones
    far = rng.normal(size=(50_000, 3)) * rng.uniform(10, 1e4, (50_000, 1))
    rx_p = np.concatenate([near, far])
    fast, _ = _compare(rx_p, rng.normal(size=(len(rx_p), 4)), tx_p, tx_q)
    counts = np.bincount(fast.zone.reshape(-1), minlength=3)
    assert counts.min() > 10_000  # every zone well represented


@pytest.mark.parametrize("params", [ModelParams(r_inner=5.0, r_outer=80.0, kappa_eq=2.0, moment=0.5),
                                    ModelParams(r_outer=12.345)])
def test_fast_path_with_other_receiver_constants(params):
    rng = np.random.default_rng(3)
    _compare(rng.uniform(-40, 40, (100_000, 3)), rng.normal(size=(100_000, 4)),
             rng.uniform(-3, 3, (3, 3)), rng.normal(size=(3, 4)), params)


def test_axis_aligned_poses_hit_exact_zeros_like_the_general_path():
    # Exact zeros in h_x (delta +-89 by the sign of h_y) on a grid of simple poses must
    # match exactly; elsewhere h_x may be a rounding residue of either sign (a boundary).
    g = np.arange(-6.0, 7.0, 1.0)
    rx_p = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3)
    quats = np.array([[1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5], [0, 0, 0, 1], [0, 1, 0, 0], [1, 0, 0, 1]], float)
    rx_q = quats[np.arange(len(rx_p)) % len(quats)]
    tx_p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    fast, general = _compare(rx_p, rx_q, tx_p, quats[:2])
    exact = (general.field[..., 0] == 0) | (general.field[..., 1] == 0)
    assert exact.sum() > 300
    for a, b in ((fast.d, general.d), (fast.delta, general.delta), (fast.zone, general.zone)):
        assert np.array_equal(a[exact], b[exact])


def test_pairs_left_to_the_general_path_are_decided_pair_by_pair(monkeypatch):
    rng = np.random.default_rng(4)
    tx_p = np.array([[0.0, 0.0, 0.0], [3.0, -2.0, 1.0]])
    tx_q = rng.normal(size=(2, 4))
    rx_p = rng.uniform(-30, 30, (64, 3))
    rx_q = rng.normal(size=(64, 4))
    rx_p[5] = tx_p[0]  # r = 0: inner, (0, 0)
    rx_p[9] = tx_p[0] + 1e-30  # r ~ 1e-30: below the fast path's range
    rx_p[17] = (1e-3, 0.0, 0.0)  # 1 mm from tx 0 with small coordinates: stays fast
    rx_q[23] = rx_q[23] * 1e-8  # |q|^2 = 1e-16 x: general path, same normalisation rules
    rx_q[31] = rx_q[31] * 1e200  # |q|^2 overflows: general path
    general = measure(rx_p, rx_q, tx_p, tx_q, want_field=True)
    for chunk in (1, 6, 64, model.CHUNK_PAIRS):
        monkeypatch.setattr(model, "CHUNK_PAIRS", chunk)
        fast = measure(rx_p, rx_q, tx_p, tx_q)
        assert np.array_equal(fast.d, general.d) and np.array_equal(fast.delta, general.delta)
        assert np.array_equal(fast.zone, general.zone)
    assert (fast.d[5, 0], fast.delta[5, 0], fast.zone[5, 0]) == (0, 0, model.ZONE_INNER)
    assert (fast.d[9, 0], fast.delta[9, 0]) == (0, 0)


def test_huge_coordinates_with_a_small_separation_take_the_general_path():
    far = 1e12
    rx_p = np.array([[far + 10.0, far, far], [far + 2.0, far, far], [far, far, far + 60.0]])
    rx_q = np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))
    tx_p, tx_q = [[far, far, far]], [[1.0, 0.0, 0.0, 0.0]]
    fast = measure(rx_p, rx_q, tx_p, tx_q)
    local = measure(rx_p - far, rx_q, [[0.0, 0.0, 0.0]], tx_q, want_field=True)
    assert fast.d.tolist() == local.d.tolist() and fast.delta.tolist() == local.delta.tolist()


@pytest.mark.parametrize("n,m", [(50, 3), (3, 40), (1, 1), (200, 7)])
def test_fast_path_blocks_and_threads_give_identical_results(monkeypatch, n, m):
    rng = np.random.default_rng(n * 100 + m)
    rx_p, tx_p = rng.uniform(-30, 30, (n, 3)), rng.uniform(-30, 30, (m, 3))
    rx_p[: min(3, n)] = tx_p[0] + rng.uniform(-2, 2, (min(3, n), 3))  # inner zone
    if n > 4:
        rx_p[4] = tx_p[0]  # at the transmitter: general path
    rx_q, tx_q = rng.normal(size=(n, 4)), rng.normal(size=(m, 4))
    ref = measure(rx_p, rx_q, tx_p, tx_q)
    for chunk in (1, 7, 64):
        monkeypatch.setattr(model, "CHUNK_PAIRS", chunk)
        for threads in (1, 3):
            got = measure(rx_p, rx_q, tx_p, tx_q, threads=threads)
            for a, b in ((got.d, ref.d), (got.delta, ref.delta), (got.zone, ref.zone)):
                assert np.array_equal(a, b) and a.dtype == b.dtype


def test_a_bad_quaternion_on_the_fast_path_names_the_smallest_norm(monkeypatch):
    monkeypatch.setattr(model, "CHUNK_PAIRS", 4)
    props.assert_the_smallest_bad_norm_is_named()


def test_pairs_a_hair_from_a_boundary_get_the_general_paths_integers():
    # Receivers on the y axis (dxy = r cbrt(kappa_eq), delta 0) a hair (1e-15 .. 1e-10
    # relative) either side of 300 cm (inner boundary), 5000 cm (outer) and 1234.5 cm
    # (a rounding point); yawed receivers a hair either side of delta = 30.5 degrees.
    c = math.cbrt(1.542)
    hairs = np.array([-1e-10, -1e-12, -1e-14, -1e-15, 0.0, 1e-15, 1e-14, 1e-12, 1e-10])
    ys = np.concatenate([b / c * (1 + hairs) for b in (3.0, 50.0, 12.345)])
    rx_p = np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], axis=1)
    rx_q = np.tile([1.0, 0.0, 0.0, 0.0], (len(ys), 1))
    yaw = np.radians(30.5) * (1 + hairs)
    rx_p = np.concatenate([rx_p, np.tile([0.0, 20.0, 0.0], (len(yaw), 1))])
    rx_q = np.concatenate([rx_q, np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)])
    fast, general = _compare(rx_p, rx_q, [[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0, 0.0]])
    assert set(fast.d[: 3 * len(hairs), 0].tolist()) >= {300, 5000, -1, 1234, 1235}
    assert set(fast.delta[3 * len(hairs):, 0].tolist()) == {-30, -31}


def test_a_scene_far_from_the_origin_takes_the_general_path_block_by_block(monkeypatch):
    # Coordinates 1e7 m from the origin, separations up to ~100 m: every pair fails the
    # cancellation guard, so whole blocks go to the general path; same integers.
    rng = np.random.default_rng(5)
    off = 1e7
    rx_p = rng.uniform(-60, 60, (3000, 3)) + off
    tx_p = rng.uniform(-20, 20, (4, 3)) + off
    rx_q, tx_q = rng.normal(size=(3000, 4)), rng.normal(size=(4, 4))
    for chunk in (64, model.CHUNK_PAIRS):
        monkeypatch.setattr(model, "CHUNK_PAIRS", chunk)
        _compare(rx_p, rx_q, tx_p, tx_q)
    # A mix: most pairs near the origin (fast), one pose far away (general), same block.
    rx_p = rng.uniform(-60, 60, (3000, 3))
    rx_p[17] += 1e9
    _compare(rx_p, rx_q, tx_p - off, tx_q)


# -- ARVA_MODEL_KERNEL (model.KERNEL): "fast" (default) or "general" --------------------

PAPER_TX = np.array([[20, 5, 0], [10, 0, 1], [20, -20, -1], [-6, 5, 0]], dtype=float)
I = (1.0, 0.0, 0.0, 0.0)


def _same(a, b):
    for x, y in ((a.d, b.d), (a.delta, b.delta), (a.zone, b.zone)):
        assert x.dtype == y.dtype and x.shape == y.shape
        differ = x != y
        assert not differ.any(), f"{int(differ.sum())} pairs differ, e.g. {x[differ][:5]} vs {y[differ][:5]}"


def _both(monkeypatch, rx_p, rx_q, tx_p, tx_q, params=PARAMS, threads=1):
    """KERNEL=fast == KERNEL=general == the general path with the field, pair for pair;
    returns the fast result."""
    monkeypatch.setattr(model, "KERNEL", "fast")
    got = measure(rx_p, rx_q, tx_p, tx_q, params, threads=threads)
    monkeypatch.setattr(model, "KERNEL", "general")
    _same(got, measure(rx_p, rx_q, tx_p, tx_q, params, threads=threads))
    monkeypatch.setattr(model, "KERNEL", "fast")
    _same(got, measure(rx_p, rx_q, tx_p, tx_q, params, want_field=True))  # never the fast path
    return got


def test_general_switches_the_fast_path_off_and_unknown_names_are_errors(monkeypatch):
    def no_fast_path(self, first, last):
        raise AssertionError("the fast path ran")

    monkeypatch.setattr(model.fast.FastPath, "run", no_fast_path)
    monkeypatch.setattr(model, "KERNEL", "general")
    assert model.measure_one((0, 0, 0), I, (20, 5, 0)) == (1905, 21)
    monkeypatch.setattr(model, "KERNEL", "fast")
    with pytest.raises(AssertionError, match="the fast path ran"):
        model.measure_one((0, 0, 0), I, (20, 5, 0))
    for name in ("compiled", "numpy", "auto", "General"):  # the removed C kernel's values too
        monkeypatch.setattr(model, "KERNEL", name)
        with pytest.raises(InputError, match=rf"^ARVA_MODEL_KERNEL: must be one of fast, general, got '{name}'$"):
            measure([[1.0, 2.0, 3.0]], [I], [[0.0, 0.0, 0.0]], [I], want_field=True)  # checked on the general path too


@pytest.mark.subprocess
def test_the_switch_is_read_from_the_environment():
    code = "from emulator.receiver import model; print(model.KERNEL, model.measure_one((0, 0, 0), (1, 0, 0, 0), (20, 5, 0)))"
    for value, out in (("general", "general (1905, 21)"), (None, "fast (1905, 21)")):
        env = {k: v for k, v in os.environ.items() if k != "ARVA_MODEL_KERNEL"}
        if value:
            env["ARVA_MODEL_KERNEL"] = value
        got = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        assert (got.returncode, got.stdout.strip()) == (0, out), got.stderr


def test_pairs_a_hair_either_side_of_every_boundary_and_the_fold(monkeypatch):
    # Receivers on the y axis of a transmitter (dxy = r cbrt(kappa_eq), delta 0) a hair
    # (1e-16 .. 1e-6 relative) either side of 300 cm (inner), 5000 cm (outer), 1234.5 cm
    # (rounding); yawed receivers a hair either side of delta = 30.5 degrees and of the
    # fold at 90 degrees.
    c = math.cbrt(1.542)
    hairs = np.concatenate([-np.logspace(-16, -6, 41), [0.0], np.logspace(-16, -6, 41)])
    ys = np.concatenate([b / c * (1 + hairs) for b in (3.0, 50.0, 12.345)])
    rx_p = np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], axis=1)
    rx_q = np.tile(I, (len(ys), 1))
    yaws = np.concatenate([np.radians(30.5) * (1 + hairs), np.radians(90.0) * (1 + hairs)])
    rx_p = np.concatenate([rx_p, np.tile([0.0, 20.0, 0.0], (len(yaws), 1))])
    rx_q = np.concatenate([rx_q, np.stack([np.cos(yaws / 2), 0 * yaws, 0 * yaws, np.sin(yaws / 2)], axis=1)])
    got = _both(monkeypatch, rx_p, rx_q, [[0.0, 0.0, 0.0]], [I])
    assert {300, 5000, -1, 1234, 1235} <= set(got.d[:, 0].tolist())
    assert {-30, -31, 89, -89} <= set(got.delta[:, 0].tolist())


@settings(max_examples=150, deadline=None)
@given(
    rx=st.lists(st.tuples(*[st.floats(-80, 80)] * 3), min_size=1, max_size=12),
    rq=st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(v * v for v in q) > 1e-6),
    tx=st.lists(st.tuples(*[st.floats(-30, 30)] * 3), min_size=1, max_size=5),
    tq=st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(v * v for v in q) > 1e-6),
)
def test_hypothesis_inputs_identical_on_both_paths(rx, rq, tx, tq):
    with pytest.MonkeyPatch.context() as mp:
        _both(mp, np.array(rx), np.tile(rq, (len(rx), 1)), np.array(tx), np.tile(tq, (len(tx), 1)))


@pytest.mark.parametrize("n, m", [(0, 4), (5, 0), (0, 0)])
def test_empty_inputs(monkeypatch, n, m):
    for kernel in model.KERNELS:
        monkeypatch.setattr(model, "KERNEL", kernel)
        got = measure(np.zeros((n, 3)), np.tile(I, (n, 1)), np.zeros((m, 3)), np.tile(I, (m, 1)))
        assert got.d.shape == got.delta.shape == got.zone.shape == (n, m)
        assert (got.d.dtype, got.delta.dtype, got.zone.dtype) == (np.int64, np.int64, np.int8)


def test_huge_and_tiny_coordinates_and_quaternions(monkeypatch):
    rng = np.random.default_rng(8)
    rx_p = rng.uniform(-60, 60, (400, 3))
    rx_q = rng.normal(size=(400, 4))
    rx_p[3] = (1e300, -1e300, 1e300)  # differences overflow: general path (outer)
    rx_p[4] = (1.7e308, 0.0, 0.0)
    rx_p[5] = (1e12 + 10.0, 1e12, 1e12)  # cancellation guard
    rx_p[6] = PAPER_TX[0] + 1e-30  # r ~ 1e-30
    rx_p[7] = PAPER_TX[2] + (1e-3, 0.0, 0.0)  # 1 mm: inner, stays fast
    rx_q[8] *= 1e-8  # |q|^2 ~ 1e-16: general path
    rx_q[9] *= 1e200  # |q|^2 overflows: general path
    rx_q[10] *= 3e-9  # norm above 1e-9 (no error), |q|^2 below the fast range
    got = _both(monkeypatch, rx_p, rx_q, PAPER_TX, [I] * 4)
    assert got.zone[3].tolist() == [2, 2, 2, 2] and got.zone[4].tolist() == [2, 2, 2, 2]
    assert (got.d[6, 0], got.delta[6, 0]) == (0, 0)
    assert (got.d[7, 2], got.delta[7, 2], got.zone[7, 2]) == (0, 0, model.ZONE_INNER)


@pytest.mark.parametrize(
    "rx_q_row, message",
    [
        ([1e-10, 0.0, 0.0, 0.0], r"^receiver.orientation: quaternion norm 1e-10 is below 1e-09$"),
        ([0.0, 0.0, 0.0, 0.0], r"^receiver.orientation: quaternion norm 0 is below 1e-09$"),
        ([math.nan, 0.0, 0.0, 1.0], r"^receiver.orientation: quaternion has a non-finite component$"),
        ([1.0, math.inf, 0.0, 0.0], r"^receiver.orientation: quaternion has a non-finite component$"),
    ],
)
def test_bad_quaternions_raise_the_same_errors_on_both_paths(monkeypatch, rx_q_row, message):
    rx_q = np.tile(I, (50, 1))
    rx_q[37] = rx_q_row
    monkeypatch.setattr(model, "CHUNK_PAIRS", 16)
    for kernel in model.KERNELS:
        monkeypatch.setattr(model, "KERNEL", kernel)
        for threads in (1, 2):
            with pytest.raises(PoseError, match=message):
                measure(np.full((50, 3), 5.0), rx_q, PAPER_TX, [I] * 4, threads=threads)


def test_bad_positions_and_transmitter_quaternions_raise_the_same_errors_on_both_paths(monkeypatch):
    rx_p = np.full((20, 3), 5.0)
    rx_p[11, 2] = math.inf
    for kernel in model.KERNELS:
        monkeypatch.setattr(model, "KERNEL", kernel)
        with pytest.raises(PoseError, match=r"^receiver.position: position has a non-finite component$"):
            measure(rx_p, np.tile(I, (20, 1)), PAPER_TX, [I] * 4)
        with pytest.raises(PoseError, match=r"^transmitter.orientation: quaternion norm 0 is below 1e-09$"):
            measure(np.ones((20, 3)), np.tile(I, (20, 1)), PAPER_TX, [I] * 3 + [(0, 0, 0, 0)])


def test_strided_fortran_and_big_endian_inputs(monkeypatch):
    rng = np.random.default_rng(9)
    rx_p = np.asfortranarray(rng.uniform(-60, 60, (4000, 3)))[::2]  # strided, Fortran order
    rx_q = rng.normal(size=(4000, 8))[::2, ::2]  # (2000, 4), both axes strided
    got = _both(monkeypatch, rx_p, rx_q, PAPER_TX.astype(">f8"), [I] * 4)
    _same(got, measure(np.ascontiguousarray(rx_p), np.ascontiguousarray(rx_q), PAPER_TX, [I] * 4))
