"""The compiled fast-path kernel (emulator/receiver/model_kernel.c) against the numpy one.

``model.KERNEL`` (from ARVA_MODEL_KERNEL) picks the implementation of the fast path. Both
leave every pair within their margins of a zone, rounding or fold boundary to the general
path, so both must give the general path's integers: identical d, delta and zone, pair for
pair, and the same errors. The rest of the model's tests run with whichever kernel the
environment selects (default: compiled when built); run them once more with
ARVA_MODEL_KERNEL=numpy to cover the numpy path (docs/model.md).
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.frames.rotation import unit_quaternion_components, x_axis_components
from emulator.receiver import model
from emulator.receiver.model import ModelParams, measure
from firmware_proto.errors import InputError, PoseError

needs_kernel = pytest.mark.skipif(model.model_kernel is None, reason="the C kernel is not built (no compiler)")
PAPER_TX = np.array([[20, 5, 0], [10, 0, 1], [20, -20, -1], [-6, 5, 0]], dtype=float)
I = (1.0, 0.0, 0.0, 0.0)


def _yaw(deg):
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def _run(kernel, monkeypatch, *args, **kw):
    monkeypatch.setattr(model, "KERNEL", kernel)
    return measure(*args, **kw)


def _same(a, b):
    for x, y in ((a.d, b.d), (a.delta, b.delta), (a.zone, b.zone)):
        assert x.dtype == y.dtype and x.shape == y.shape
        differ = x != y
        assert not differ.any(), f"{int(differ.sum())} pairs differ, e.g. {x[differ][:5]} vs {y[differ][:5]}"


def _all_three(monkeypatch, rx_p, rx_q, tx_p, tx_q, params=ModelParams(), threads=1):
    """compiled == numpy == general path, pair for pair; returns the compiled result."""
    comp = _run("compiled", monkeypatch, rx_p, rx_q, tx_p, tx_q, params, threads=threads)
    nump = _run("numpy", monkeypatch, rx_p, rx_q, tx_p, tx_q, params, threads=threads)
    general = measure(rx_p, rx_q, tx_p, tx_q, params, want_field=True)  # never the fast path
    _same(comp, nump)
    _same(comp, general)
    return comp


def test_kernel_is_built_where_a_compiler_is():
    # `pip install -e .` builds it when cc exists (setup.py, optional=True): a silently
    # failed build would leave every other test here skipped.
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on this host: the numpy fast path is the one in use")
    assert model.model_kernel is not None, "emulator.receiver.model_kernel is not built: run pip install -e ."


def test_auto_prefers_the_compiled_kernel_and_unknown_names_are_errors(monkeypatch):
    monkeypatch.setattr(model, "KERNEL", "auto")
    assert model._compiled_kernel() is (model.model_kernel is not None)
    monkeypatch.setattr(model, "KERNEL", "numpy")
    assert model._compiled_kernel() is False
    monkeypatch.setattr(model, "KERNEL", "fortran")
    with pytest.raises(InputError, match=r"^ARVA_MODEL_KERNEL: must be one of auto, compiled, numpy, got 'fortran'$"):
        measure([[1.0, 2.0, 3.0]], [I], [[0.0, 0.0, 0.0]], [I])


def test_asking_for_the_compiled_kernel_when_it_is_not_built_is_an_input_error(monkeypatch):
    monkeypatch.setattr(model, "model_kernel", None)
    monkeypatch.setattr(model, "KERNEL", "compiled")
    with pytest.raises(InputError, match=r"^ARVA_MODEL_KERNEL=compiled: the extension .* is not built"):
        measure([[1.0, 2.0, 3.0]], [I], [[0.0, 0.0, 0.0]], [I])
    monkeypatch.setattr(model, "KERNEL", "auto")  # auto falls back to numpy: same integers
    assert model.measure_one((0, 0, 0), I, (20, 5, 0)) == (1905, 21)


@needs_kernel
@pytest.mark.parametrize(
    "rx_p, rx_q, expected",
    [  # the golden paper scene of tests/test_model.py::test_golden_paper_scene (worked by hand)
        ((0, 0, 0), I, [(1905, 21), (926, 0), (2808, -72), (761, -62)]),
        ((10, 0, 0), I, [(1053, 41), (116, 0), (2392, 71), (1555, -26)]),
        ((5, 5, 2), _yaw(30), [(1400, -30), (714, 78), (3081, 51), (1042, -30)]),
        ((18, 4, 0), I, [(211, 0), (853, 41), (2775, 14), (2203, -4)]),
        ((-30, -20, 1.5), (0.9, 0.1, -0.2, 0.3), [(-1, -1), (4384, 3), (4714, -42), (3582, 40)]),
        ((-60, 0, 0), I, [(-1, -1), (-1, -1), (-1, -1), (4978, 8)]),
    ],
)
def test_golden_paper_scene_on_both_kernels(monkeypatch, rx_p, rx_q, expected):
    for kernel in ("compiled", "numpy"):
        got = _run(kernel, monkeypatch, [rx_p], [rx_q], PAPER_TX, [I] * 4)
        assert list(zip(got.d[0].tolist(), got.delta[0].tolist())) == expected, kernel


@needs_kernel
@pytest.mark.parametrize("seed", [0, 1])
def test_random_pairs_identical_on_both_kernels(monkeypatch, seed):
    rng = np.random.default_rng(100 + seed)
    n = 60_000  # x 4 transmitters: 240,000 pairs, all zones
    rx_p = np.concatenate([rng.uniform(-60, 60, (n - 10_000, 3)), rng.uniform(-4, 4, (10_000, 3))])
    rx_q = rng.normal(size=(n, 4)) * rng.uniform(1e-3, 1e3, (n, 1))  # unnormalised
    tx_p, tx_q = rng.uniform(-20, 20, (4, 3)), rng.normal(size=(4, 4))
    rx_p[n - 10_000:] += tx_p[0]
    got = _all_three(monkeypatch, rx_p, rx_q, tx_p, tx_q)
    counts = np.bincount(got.zone.reshape(-1), minlength=3)
    assert counts.min() > 1_000, counts  # inner, mid and outer all represented


@needs_kernel
def test_pairs_a_hair_from_each_boundary(monkeypatch):
    # Receivers on the y axis of a transmitter (dxy = r cbrt(kappa_eq), delta 0) a hair
    # either side of 300 cm (inner), 5000 cm (outer), 1234.5 cm (rounding); yawed
    # receivers a hair either side of delta = 30.5 degrees and of the fold at 90 degrees.
    c = math.cbrt(1.542)
    hairs = np.concatenate([-np.logspace(-16, -6, 41), [0.0], np.logspace(-16, -6, 41)])
    ys = np.concatenate([b / c * (1 + hairs) for b in (3.0, 50.0, 12.345)])
    rx_p = np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], axis=1)
    rx_q = np.tile(I, (len(ys), 1))
    yaws = np.concatenate([np.radians(30.5) * (1 + hairs), np.radians(90.0) * (1 + hairs)])
    rx_p = np.concatenate([rx_p, np.tile([0.0, 20.0, 0.0], (len(yaws), 1))])
    rx_q = np.concatenate([rx_q, np.stack([np.cos(yaws / 2), 0 * yaws, 0 * yaws, np.sin(yaws / 2)], axis=1)])
    got = _all_three(monkeypatch, rx_p, rx_q, [[0.0, 0.0, 0.0]], [I])
    assert {300, 5000, -1, 1234, 1235} <= set(got.d[:, 0].tolist())
    assert {-30, -31, 89, -89} <= set(got.delta[:, 0].tolist())
    # The kernel itself leaves the closest ones undecided (zone -1), hairs beyond its
    # margins (1e-8 relative) decided: of 41 hairs a side, those from 1e-8 to 1e-6.
    tab = model._tables(ModelParams())
    tx = model._kernel_tx(np.zeros((1, 3)), x_axis_components(unit_quaternion_components([I])), tab.lam)
    d, delta, zone = np.empty((len(rx_p), 1), np.int64), np.empty((len(rx_p), 1), np.int64), np.empty((len(rx_p), 1), np.int8)
    count = model.model_kernel.fast_pairs(np.ascontiguousarray(rx_p), np.ascontiguousarray(rx_q), tx,
                                            tab.kernel_consts, d, delta, zone)
    assert count == int((zone < 0).sum()) and 100 < count < len(rx_p) - 40


@needs_kernel
@settings(max_examples=150, deadline=None)
@given(
    rx=st.lists(st.tuples(*[st.floats(-80, 80)] * 3), min_size=1, max_size=12),
    rq=st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(v * v for v in q) > 1e-6),
    tx=st.lists(st.tuples(*[st.floats(-30, 30)] * 3), min_size=1, max_size=5),
    tq=st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(v * v for v in q) > 1e-6),
)
def test_hypothesis_inputs_identical_on_both_kernels(rx, rq, tx, tq):
    with pytest.MonkeyPatch.context() as mp:
        _all_three(mp, np.array(rx), np.tile(rq, (len(rx), 1)), np.array(tx), np.tile(tq, (len(tx), 1)))


@needs_kernel
@pytest.mark.parametrize("params", [ModelParams(r_inner=5.0, r_outer=80.0, kappa_eq=2.0, moment=0.5),
                                    ModelParams(r_outer=12.345)])
def test_other_receiver_constants(monkeypatch, params):
    rng = np.random.default_rng(7)
    _all_three(monkeypatch, rng.uniform(-40, 40, (30_000, 3)), rng.normal(size=(30_000, 4)),
               rng.uniform(-3, 3, (3, 3)), rng.normal(size=(3, 4)), params)


@needs_kernel
@pytest.mark.parametrize("chunk", [1, 5, 64, model.CHUNK_PAIRS])
def test_two_threads_and_any_block_size(monkeypatch, chunk):
    monkeypatch.setattr(model, "CHUNK_PAIRS", chunk)
    rng = np.random.default_rng(chunk)
    rx_p, rx_q = rng.uniform(-60, 60, (3000, 3)), rng.normal(size=(3000, 4))
    rx_p[7] = PAPER_TX[1]  # r = 0: the general path, inside a compiled block
    one = _all_three(monkeypatch, rx_p, rx_q, PAPER_TX, [I] * 4)
    two = _all_three(monkeypatch, rx_p, rx_q, PAPER_TX, [I] * 4, threads=2)
    _same(one, two)
    assert (one.d[7, 1], one.delta[7, 1], one.zone[7, 1]) == (0, 0, model.ZONE_INNER)


@needs_kernel
@pytest.mark.parametrize("n, m", [(0, 4), (5, 0), (0, 0)])
def test_empty_inputs(monkeypatch, n, m):
    for kernel in ("compiled", "numpy"):
        got = _run(kernel, monkeypatch, np.zeros((n, 3)), np.tile(I, (n, 1)), np.zeros((m, 3)), np.tile(I, (m, 1)))
        assert got.d.shape == got.delta.shape == got.zone.shape == (n, m)
        assert (got.d.dtype, got.delta.dtype, got.zone.dtype) == (np.int64, np.int64, np.int8)


@needs_kernel
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
    got = _all_three(monkeypatch, rx_p, rx_q, PAPER_TX, [I] * 4)
    assert got.zone[3].tolist() == [2, 2, 2, 2] and got.zone[4].tolist() == [2, 2, 2, 2]
    assert (got.d[6, 0], got.delta[6, 0]) == (0, 0)
    # Every pose far away: whole blocks to the general path.
    _all_three(monkeypatch, rx_p + 1e7, rx_q, PAPER_TX + 1e7, [I] * 4)


@needs_kernel
@pytest.mark.parametrize(
    "rx_q_row, message",
    [
        ([1e-10, 0.0, 0.0, 0.0], r"^receiver.orientation: quaternion norm 1e-10 is below 1e-09$"),
        ([0.0, 0.0, 0.0, 0.0], r"^receiver.orientation: quaternion norm 0 is below 1e-09$"),
        ([math.nan, 0.0, 0.0, 1.0], r"^receiver.orientation: quaternion has a non-finite component$"),
        ([1.0, math.inf, 0.0, 0.0], r"^receiver.orientation: quaternion has a non-finite component$"),
    ],
)
def test_bad_quaternions_raise_the_same_errors(monkeypatch, rx_q_row, message):
    rx_q = np.tile(I, (50, 1))
    rx_q[37] = rx_q_row
    for kernel in ("compiled", "numpy"):
        for threads in (1, 2):
            monkeypatch.setattr(model, "CHUNK_PAIRS", 16)
            with pytest.raises(PoseError, match=message):
                _run(kernel, monkeypatch, np.full((50, 3), 5.0), rx_q, PAPER_TX, [I] * 4, threads=threads)


@needs_kernel
def test_bad_positions_and_transmitter_quaternions_raise_the_same_errors(monkeypatch):
    rx_p = np.full((20, 3), 5.0)
    rx_p[11, 2] = math.inf
    for kernel in ("compiled", "numpy"):
        with pytest.raises(PoseError, match=r"^receiver.position: position has a non-finite component$"):
            _run(kernel, monkeypatch, rx_p, np.tile(I, (20, 1)), PAPER_TX, [I] * 4)
        with pytest.raises(PoseError, match=r"^transmitter.orientation: quaternion norm 0 is below 1e-09$"):
            _run(kernel, monkeypatch, np.ones((20, 3)), np.tile(I, (20, 1)), PAPER_TX, [I] * 3 + [(0, 0, 0, 0)])


@needs_kernel
def test_the_kernel_checks_its_buffers():
    k = model.model_kernel
    tab = model._tables(ModelParams())
    p, q, tx = np.zeros((2, 3)), np.tile(I, (2, 1)), np.zeros((1, 10))
    d, delta, zone = np.empty((2, 1), np.int64), np.empty((2, 1), np.int64), np.empty((2, 1), np.int8)
    with pytest.raises(ValueError, match=r"^model_kernel.fast_pairs: rx_q has 32 bytes, expected 64$"):
        k.fast_pairs(p, q[:1], tx, tab.kernel_consts, d, delta, zone)
    with pytest.raises(ValueError, match=r"zone has 1 bytes, expected 2$"):
        k.fast_pairs(p, q, tx, tab.kernel_consts, d, delta, zone[:1])
    with pytest.raises(TypeError):  # read-only output
        k.fast_pairs(p, q, tx, tab.kernel_consts, d, delta, np.broadcast_to(np.int8(0), (2, 1)))


@needs_kernel
def test_strided_fortran_and_big_endian_inputs(monkeypatch):
    rng = np.random.default_rng(9)
    rx_p = np.asfortranarray(rng.uniform(-60, 60, (4000, 3)))[::2]  # strided, Fortran order
    rx_q = rng.normal(size=(4000, 8))[::2, ::2]  # (2000, 4), both axes strided
    tx_p = PAPER_TX.astype(">f8")
    got = _all_three(monkeypatch, rx_p, rx_q, tx_p, [I] * 4)
    _same(got, _run("compiled", monkeypatch, np.ascontiguousarray(rx_p), np.ascontiguousarray(rx_q), PAPER_TX, [I] * 4))


def test_the_switch_is_checked_on_the_general_path_too(monkeypatch):
    monkeypatch.setattr(model, "KERNEL", "Compiled")
    with pytest.raises(InputError, match=r"^ARVA_MODEL_KERNEL: must be one of auto, compiled, numpy, got 'Compiled'$"):
        measure([[1.0, 2.0, 3.0]], [I], [[0.0, 0.0, 0.0]], [I], want_field=True)
