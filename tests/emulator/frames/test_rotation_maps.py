"""Quaternion products, exponential / logarithm maps and the trajectory's slerp
(emulator.frames.rotation, emulator.frames.trajectory) against scipy's Rotation, which
the emulator no longer imports (its start-up cost), and the import guard itself."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
import pytest
from scipy.spatial.transform import Rotation, Slerp

from emulator.frames.rotation import (
    quaternion_conjugates,
    quaternion_products,
    quaternion_rotvecs,
    rotvec_quaternions,
)
from emulator.frames.trajectory import Trajectory

TOL = 4e-15

unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: sum(c * c for c in q) > 1e-6)
# Rotation vectors from 0 over the Taylor switch (1e-3 rad) up to just below pi.
rotvec = st.tuples(
    st.floats(0, 3.1, allow_nan=False),
    st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: sum(c * c for c in v) > 1e-6),
).map(lambda av: av[0] * np.asarray(av[1]) / np.linalg.norm(av[1]))


def _unit(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q)


def _scipy(q) -> Rotation:
    return Rotation.from_quat(q, scalar_first=True)


@settings(max_examples=200, deadline=None)
@given(unit, unit)
def test_product_is_scipys_composition(p, q):
    p, q = _unit(p), _unit(q)
    want = (_scipy(p) * _scipy(q)).as_quat(scalar_first=True)
    got = quaternion_products(p, q)
    if np.dot(want, got) < 0:  # scipy may return either sign of the same rotation
        want = -want
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


@settings(max_examples=200, deadline=None)
@given(rotvec)
def test_exp_and_log_maps_are_scipys(v):
    q = rotvec_quaternions(v)
    want = _scipy(q).as_quat(scalar_first=True)
    np.testing.assert_allclose(q, Rotation.from_rotvec(v).as_quat(scalar_first=True), rtol=0, atol=TOL)
    assert abs(np.linalg.norm(q) - 1.0) < TOL
    np.testing.assert_allclose(quaternion_rotvecs(q), _scipy(want).as_rotvec(), rtol=0, atol=8 * TOL)
    np.testing.assert_allclose(quaternion_rotvecs(-q), quaternion_rotvecs(q), rtol=0, atol=0)


def test_small_angles_use_the_series_exactly_like_scipy():
    # 1e-3 rad is the switch; 1e-20 would give 0/0 without the series.
    for a in (0.0, 1e-20, 1e-8, 9.99e-4, 1e-3, 1.001e-3):
        v = np.array([a, 0.0, 0.0])
        q = rotvec_quaternions(v)
        assert np.all(np.isfinite(q))
        np.testing.assert_allclose(q, Rotation.from_rotvec(v).as_quat(scalar_first=True), rtol=0, atol=TOL)
        np.testing.assert_allclose(quaternion_rotvecs(q), v, rtol=0, atol=TOL)


def test_half_turns_take_scipys_sign():
    """w = 0: +pi or -pi about the axis; scipy's choice (first non-zero component of q
    positive) decides which way paper_walk.toml's 180-degree turns go."""
    c = 0.7071067811865476
    for q in ([0.0, 0.0, 0.0, -1.0], [0.0, 0.0, 0.0, 1.0], [0.0, -c, c, 0.0], [0.0, 0.0, -1.0, 0.0],
              [-0.0, 0.6, 0.0, -0.8]):
        np.testing.assert_array_equal(quaternion_rotvecs(np.asarray(q)), _scipy(q).as_rotvec())
    # the paper walk's turn at t = 80 s: yaw +90 -> -90 degrees, through +180 about z as before
    traj = Trajectory(np.array([80.0, 90.0]), np.zeros((2, 3)), np.array([[c, 0, 0, c], [c, 0, 0, -c]]))
    _, q = traj.at([85.0])
    want = Slerp([80.0, 90.0], _scipy([[c, 0, 0, c], [c, 0, 0, -c]]))([85.0]).as_quat(scalar_first=True)
    np.testing.assert_allclose(q, want, rtol=0, atol=TOL)


def test_conjugate_undoes_the_rotation():
    q = _unit([0.3, -0.2, 0.9, 0.1])
    np.testing.assert_allclose(quaternion_products(quaternion_conjugates(q), q), [1.0, 0.0, 0.0, 0.0], atol=TOL)


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 12), st.integers(0, 2**32 - 1))
def test_trajectory_slerp_is_scipys(k, seed):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.05, 20.0, k))
    quats = rng.normal(size=(k, 4))  # not unit: the trajectory normalises, as scipy does
    traj = Trajectory(times, rng.normal(size=(k, 3)), quats)
    t = np.concatenate([times, rng.uniform(times[0] - 5.0, times[-1] + 5.0, 200)])
    _, got = traj.at(t)
    want = Slerp(times, _scipy(quats))(np.clip(t, times[0], times[-1])).as_quat(scalar_first=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


def test_waypoints_are_hit_and_held():
    q0, q1 = _unit([1, 0, 0, 1]), _unit([1, 0, 0, -1])  # +90 and -90 degrees of yaw
    traj = Trajectory(np.array([10.0, 20.0]), np.zeros((2, 3)), np.stack([q0, q1]))
    _, q = traj.at([0.0, 10.0, 15.0, 20.0, 99.0])
    q = q * np.sign(q @ np.array([0.0, 0.0, 0.0, 1.0]))[:, None]  # q and -q: the same rotation
    q0, q1 = q0 * np.sign(q0[3]), q1 * np.sign(q1[3])
    np.testing.assert_allclose(q[[0, 1]], [q0, q0], atol=TOL)
    np.testing.assert_allclose(q[[3, 4]], [q1, q1], atol=TOL)
    # halfway through this half turn (+180 degrees about z, scipy's sign): yaw 180 degrees
    np.testing.assert_allclose(q[2], [0.0, 0.0, 0.0, 1.0], atol=TOL)


@pytest.mark.subprocess
def test_the_emulator_imports_no_scipy():
    """arva-emulate's start-up: importing scipy.spatial alone cost ~0.3 s of CPU."""
    code = "import sys, emulator.cli; print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"
