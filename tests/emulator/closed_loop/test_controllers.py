"""Controllers: eq. 10 exactly, height hold, marking, strips, the rescuer's logic."""

import dataclasses
import math

import numpy as np
import pytest

from emulator.closed_loop.controllers import (
    FINE,
    EpochArrays,
    FluxFollower,
    FluxParams,
    FluxState,
    Observation,
    ReceiverOnlySearch,
    RxParams,
    RxState,
    StripSearch,
    flux_epoch,
    make_controller,
    rx_arrive,
    rx_epoch,
    speed_law,
)
from emulator.closed_loop.vehicle import VehicleSpec
from emulator.receiver.model import ModelParams

SPEC = VehicleSpec(v_max=1.0, k_c=0.2, k_z=1.5, r_s=1.0, control_rate_hz=10.0)


def obs(t=0.0, x=0.0, y=0.0, yaw=0.0, height=1.0, ids=(1,), d=(1000,), delta=(0,), field=((1e-3, 0.0, 0.0),), new=True):
    return Observation(t, x, y, 1.0, yaw, height, list(ids), list(d), list(delta), [list(f) for f in field], new)


# --------------------------------------------------------------------------- eq. 10
def test_speed_law():
    assert speed_law(2.0, 0.0) == 0.0
    assert speed_law(2.0, 1.0) == pytest.approx(math.sqrt(2.0))
    assert speed_law(2.0, 1e6) == pytest.approx(2.0)


def test_flux_follower_is_eq_10():
    c = FluxFollower(SPEC)
    h = (3e-4, -4e-4, 1.2e-3)
    vx, vy, vz = c.command(obs(field=[h], height=0.6))
    n = math.sqrt(sum(v * v for v in h))
    g = 0.2 * n ** (-1 / 3)
    s = 1.0 * g / math.sqrt(1 + g * g)
    assert (vx, vy) == pytest.approx((s * h[0] / n, s * h[1] / n), rel=1e-12)
    assert vz == pytest.approx(1.5 * (1.0 - 0.6))  # V_z = k_z (r_s - y_s)


def test_flux_follower_rotates_the_field_by_the_yaw_and_holds_between_epochs():
    c = FluxFollower(SPEC)
    vx, vy, _ = c.command(obs(yaw=math.pi / 2, field=[(2e-3, 0.0, 0.0)]))
    assert vx == pytest.approx(0.0, abs=1e-15) and vy > 0  # receiver x points north
    held = c.command(obs(t=0.1, yaw=math.pi / 2, field=[(0.0, 5e-3, 0.0)], new=False))
    assert held[:2] == (vx, vy)


def test_flux_follower_follows_plus_h_and_reverses_only_when_asked():
    epochs = [obs(t=k, d=(1000,), field=[(-(1e-3) / (1 + 0.1 * k) ** 3, 0.0, 0.0)]) for k in range(12)]
    plain, rev = FluxFollower(SPEC), FluxFollower(VehicleSpec(flux_reverse=True))
    vx_plain = [plain.command(o)[0] for o in epochs]
    vx_rev = [rev.command(o)[0] for o in epochs]
    assert all(v < 0 for v in vx_plain)  # +h: west, though |h| keeps falling
    # |h|^(-1/3) grows 10 % per epoch: the 5th epoch turns round, and (|h| still falling
    # on the new side) 5 epochs later it turns back.
    assert [v < 0 for v in vx_rev] == [True] * 4 + [False] * 5 + [True] * 3


def test_flux_follower_locates_when_settled_and_marks_the_id():
    c = FluxFollower(SPEC)
    vertical = [(1e-6, 0.0, 5e-2), (9e-3, 0.0, 1e-2)]  # id 1 nearly vertical: slow
    for k in range(3):
        c.command(obs(t=k, x=2.0, y=3.0, ids=(1, 2), d=(150, 900), delta=(0, 10), field=vertical))
    assert [(e.id, e.t, e.x, e.y) for e in c.located] == [(1, 2.0, 2.0, 3.0)]
    vx, vy, _ = c.command(obs(t=3, ids=(1, 2), d=(150, 900), delta=(0, 10), field=vertical))
    n = math.hypot(9e-3, 1e-2)
    g = 0.2 * n ** (-1 / 3)
    assert c.target == 2  # the marked id is ignored, the next one followed
    assert (vx, vy) == pytest.approx((g / math.sqrt(1 + g * g) * 9e-3 / n, 0.0))


def test_flux_follower_waits_for_a_signal_without_search_area():
    c = FluxFollower(SPEC)
    assert c.command(obs(ids=(-1,), d=(-1,), delta=(-1,), field=[(0, 0, 0)], height=1.0)) == (0.0, 0.0, 0.0)
    assert not c.exhausted and c.phase == "search"


def test_lost_signal_keeps_the_last_command_for_three_epochs():
    c = FluxFollower(SPEC)
    v = c.command(obs())
    none = dict(ids=(-1,), d=(-1,), delta=(-1,), field=[(0, 0, 0)])
    assert [c.command(obs(t=k, **none))[:2] == v[:2] for k in (1, 2, 3, 4)] == [True, True, True, False]


# --------------------------------------------------------------------------- strips
def test_strip_search_waypoints_and_speed():
    s = StripSearch((0.0, 0.0, 80.0, 80.0), 30.0)
    assert s.waypoints == [(15.0, 0.0), (15.0, 80.0), (45.0, 80.0), (45.0, 0.0), (75.0, 0.0), (75.0, 80.0)]
    assert s.velocity(0.0, 0.0, 2.0) == pytest.approx((2.0 * 15 / math.hypot(15, 0), 0.0))
    assert s.velocity(14.9, 0.0, 2.0) == pytest.approx((0.0, 2.0), abs=0.01)  # reached: next waypoint
    assert s.velocity(15.0, 79.5, 2.0) == pytest.approx((0.0, 0.5))  # no overshoot


def test_controller_with_search_area_flies_strips_then_is_exhausted():
    spec = VehicleSpec(search_area=(0.0, 0.0, 10.0, 10.0), strip_width=20.0, v_max=2.0)
    c = make_controller(spec)
    none = dict(ids=(-1,), d=(-1,), delta=(-1,), field=[(0, 0, 0)])
    assert c.command(obs(**none))[:2] == pytest.approx((2.0, 0.0))
    c.strips.next = len(c.strips.waypoints)
    assert c.exhausted


def test_make_controller():
    assert type(make_controller(VehicleSpec(controller="flux"))) is FluxFollower
    assert type(make_controller(VehicleSpec(controller="receiver_only"))) is ReceiverOnlySearch
    with pytest.raises(ValueError, match="external_mavlink"):
        make_controller(VehicleSpec(controller="external_mavlink"))


# --------------------------------------------------------------------------- rescuer
def test_receiver_only_heading_from_delta_with_continuity_and_speed_from_d():
    c = ReceiverOnlySearch(SPEC)
    vx, vy, _ = c.command(obs(yaw=0.0, d=(2000,), delta=(30,)))
    s = speed_law(1.0, 0.2 * (4 * math.pi / 1.542) ** (1 / 3) * 20.0)
    assert (vx, vy) == pytest.approx((s * math.cos(math.radians(30)), s * math.sin(math.radians(30))))
    # delta -80 folds: the line at -80 deg or 100 deg; 100 deg continues a 30 deg heading.
    vx, vy, _ = c.command(obs(t=1, d=(1900,), delta=(-80,)))
    assert math.degrees(math.atan2(vy, vx)) == pytest.approx(100.0)


def test_receiver_only_turns_around_when_d_grows():
    c = ReceiverOnlySearch(SPEC)
    headings = []
    for k, d in enumerate([2000, 1950, 1990, 2100, 2300, 2400, 2600]):
        vx, vy, _ = c.command(obs(t=k, d=(d,), delta=(0,)))
        headings.append(round(math.degrees(math.atan2(vy, vx))))
    # 2300 > 1.1 * 1950 + 100 = 2245 at epoch 4 (>= 5 epochs since the start): turn.
    assert headings == [0, 0, 0, 0, 180, 180, 180]


def bowl(x, y, a=(3.0, -2.0), dz=1.5):
    """Inner-zone d (cm) over a transmitter dz below at a: 1.1 times the distance."""
    return round(110 * math.sqrt((x - a[0]) ** 2 + (y - a[1]) ** 2 + dz * dz))


def fly(controller, d_of, x=0.0, y=0.0, t_max=400.0, rate=10):
    """A bare loop: 1 Hz epochs of d_of(x, y), 10 Hz control, no vehicle limits."""
    dt = 1.0 / rate
    for tick in range(int(t_max * rate)):
        new = tick % rate == 0
        if new:
            d = d_of(x, y)
            reading = dict(ids=(1,), d=(d,), delta=(0 if d <= 300 else 45,))
        vx, vy, _ = controller.command(obs(t=tick * dt, x=x, y=y, field=[(0, 0, 0)], new=new, **reading))
        x, y = x + vx * dt, y + vy * dt
        if controller.located:
            break
    return controller.located


def test_receiver_only_brackets_the_minimum_in_the_inner_zone():
    located = fly(ReceiverOnlySearch(SPEC), bowl, x=2.0, y=-1.0)
    assert len(located) == 1
    ev = located[0]
    assert math.hypot(ev.x - 3.0, ev.y + 2.0) < 0.15
    assert ev.t < 60


def test_receiver_only_stuck_in_the_mid_zone_searches_from_the_best_point():
    # d never reaches the inner zone and stays flat: stuck after 20 epochs, then the
    # fine search brackets the shallow minimum at (-4, 0) (a deep burial: d < 500).
    c = ReceiverOnlySearch(SPEC)
    located = fly(c, lambda x, y: 400 + round(10 * math.hypot(x + 4.0, y)), x=-1.0, y=0.5)
    assert len(located) == 1 and math.hypot(located[0].x + 4.0, located[0].y) < 0.5


# --------------------------------------------------------------------------- arrays
def _row(ep, i):
    pick = lambda a: None if a is None else a[i : i + 1]  # noqa: E731
    return EpochArrays(ep.t, *(pick(getattr(ep, f)) for f in ("x", "y", "yaw", "ids", "d", "delta", "field", "marked")))


def _same_rows(batch, alone):
    for f in dataclasses.fields(batch):
        got = getattr(batch, f.name)
        want = np.array([getattr(s, f.name)[0] for s in alone])
        assert np.array_equal(got, want), f.name


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_array_decisions_of_a_run_do_not_depend_on_its_batch(seed):
    """flux_epoch, rx_epoch and rx_arrive on B runs at once leave each run in the state
    it reaches alone (B = 1) — random epochs: lost signals, marked ids, the inner zone,
    stuck approaches, fine-search lines and their ends."""
    rng = np.random.default_rng(seed)
    b, c = 32, 3
    specs = [VehicleSpec(v_max=float(rng.choice([0.5, 1, 2])), k_c=float(rng.choice([0.1, 0.2, 0.4])),
                         flux_reverse=bool(i % 2), v_stop=0.05) for i in range(b)]
    fpar, rpar = FluxParams.of(specs), RxParams.of(specs, ModelParams())
    flux, rx = FluxState.empty(b), RxState.empty(b)
    flux1, rx1 = [FluxState.empty(1) for _ in range(b)], [RxState.empty(1) for _ in range(b)]
    x, y = rng.uniform(0, 80, b), rng.uniform(0, 80, b)
    marks = arrivals = 0
    seen: set[str] = set()
    for k in range(200):
        ids = rng.integers(-1, 4, (b, c))
        if k // 10 % 2:
            ids[1::6] = -1  # a fifth of the runs hear nothing for 10 epochs
        ids[2::3] = [1, 2, 3]  # a third hear the same ids, never in the inner zone:
        low = np.where(np.arange(b) % 3 == 2, 600, 20)[:, None]  # stuck, bracketing, retrying
        d = np.where(ids >= 0, rng.integers(low, 2500, (b, c)), -1)
        field = rng.normal(size=(b, c, 3)) * 10.0 ** rng.uniform(-7, -1, (b, 1, 1))
        field[::4, :, :2] *= 1e-4  # a quarter of the runs over a vertical field: they settle
        ep = EpochArrays(float(k), x, y, rng.uniform(-3, 3, b), ids, d, rng.integers(-90, 91, (b, c)), field,
                         rng.random((b, c)) < 0.2)
        got, located = flux_epoch(flux, ep, fpar)
        by_row = dict(zip(np.flatnonzero(got).tolist(), located.tolist()))
        rx_epoch(rx, ep, rpar)
        for i in range(b):
            one, loc1 = flux_epoch(flux1[i], _row(ep, i), fpar.take([i]))
            assert (bool(one[0]), loc1.tolist()) == (bool(got[i]), [by_row[i]] if got[i] else [])
            rx_epoch(rx1[i], _row(ep, i), rpar.take([i]))
        marks += int(got.sum())
        # Some runs on their way back arrive on the minimum.
        back = np.flatnonzero((rx.phase == FINE) & rx.line & rx.going_back & (rng.random(b) < 0.8))
        if back.size:
            part = rx.take(back)
            done, ids_b, lx, ly, vx, vy = rx_arrive(part, x[back], y[back], rpar.take(back))
            rx.put(back, part)
            where = {r: (i, xx, yy) for r, i, xx, yy in zip(np.flatnonzero(done), ids_b, lx, ly)}
            for r, i in enumerate(back):
                one = rx_arrive(rx1[i], x[i : i + 1], y[i : i + 1], rpar.take([i]))
                assert (bool(one[0][0]), float(one[4][0]), float(one[5][0])) == (bool(done[r]), vx[r], vy[r])
                assert [(a[0], b_[0], c_[0]) for a, b_, c_ in [one[1:4]] if a.size] == ([where[r]] if done[r] else [])
                arrivals += 1
        _same_rows(flux, flux1)
        _same_rows(rx, rx1)
        seen |= {name for name, hit in (("reversal", rx.reversals > 0), ("retry", rx.attempts > 0),
                                        ("rx located", rx.approaching[back] < 0 if back.size else rx.line & False),
                                        ("lost", flux.lost > 3)) if hit.any()}
        x, y = x + rng.normal(0, 0.5, b), y + rng.normal(0, 0.5, b)
    assert marks > 0 and arrivals > 0
    assert seen == {"reversal", "retry", "rx located", "lost"}
