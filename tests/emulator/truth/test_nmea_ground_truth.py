"""Ground-truth sentence generation and the heading/roll/pitch convention."""

from __future__ import annotations

import math
import re
from datetime import datetime, timedelta, timezone
from functools import reduce

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from pynmeagps import NMEAReader
from pynmeagps.nmeatypes_core import VALCKSUM, VALMSGID
from scipy.spatial.transform import Rotation

from emulator.frames.attitude import hpr_to_quaternion, quaternion_to_hpr, wrap_heading
from emulator.truth.nmea import (
    KNOTS_PER_MPS,
    gga_sentence,
    gps_sentences,
    pashr_from_quaternion,
    pashr_from_quaternions,
    pashr_sentence,
    rmc_sentence,
    speed_course_from_enu,
)
from emulator.frames.rotation import quaternion_matrices
from firmware_proto.errors import InputError, PoseError

UTC = timezone.utc
T0 = datetime(2024, 3, 1, 12, 34, 56, 789000, tzinfo=UTC)


def with_checksum(body: str) -> bytes:
    """``$body*hh\\r\\n`` with the checksum computed here, independently of pynmeagps."""
    cs = reduce(lambda a, c: a ^ ord(c), body, 0)
    return f"${body}*{cs:02X}\r\n".encode()


def matrix(q) -> np.ndarray:
    return quaternion_matrices(np.asarray(q, dtype=float))


# ---------------------------------------------------------------------------- convention


def test_heading_90_points_body_x_east():
    r = matrix(hpr_to_quaternion(90.0, 0.0, 0.0))
    np.testing.assert_allclose(r[:, 0], [1.0, 0.0, 0.0], atol=1e-15)  # x forward -> east
    np.testing.assert_allclose(r[:, 1], [0.0, 1.0, 0.0], atol=1e-15)  # y left -> north
    np.testing.assert_allclose(r[:, 2], [0.0, 0.0, 1.0], atol=1e-15)


def test_heading_0_points_north_and_identity_is_heading_90():
    np.testing.assert_allclose(matrix(hpr_to_quaternion(0.0, 0.0, 0.0))[:, 0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(hpr_to_quaternion(90.0, 0.0, 0.0), [1.0, 0.0, 0.0, 0.0], atol=1e-15)
    h, r, p = quaternion_to_hpr([1.0, 0.0, 0.0, 0.0])
    assert (float(h), float(r), float(p)) == (90.0, 0.0, 0.0)


def test_heading_is_clockwise_seen_from_above():
    # Heading 45: halfway from north to east.
    x = matrix(hpr_to_quaternion(45.0, 0.0, 0.0))[:, 0]
    np.testing.assert_allclose(x, [math.sqrt(0.5), math.sqrt(0.5), 0.0], atol=1e-15)


def test_pitch_positive_is_nose_up():
    x = matrix(hpr_to_quaternion(0.0, 0.0, 30.0))[:, 0]
    np.testing.assert_allclose(x, [0.0, math.cos(math.radians(30)), 0.5], atol=1e-15)


def test_roll_positive_is_right_side_down():
    y_left = matrix(hpr_to_quaternion(0.0, 30.0, 0.0))[:, 1]
    assert y_left[2] == pytest.approx(0.5, abs=1e-15)  # left up = right down
    np.testing.assert_allclose(y_left, [-math.cos(math.radians(30)), 0.0, 0.5], atol=1e-15)


@given(
    st.floats(0.0, 360.0, exclude_max=True),
    st.floats(-180.0, 180.0),
    st.floats(-89.0, 89.0),
)
def test_same_as_aerospace_ned_frd_zyx(h, r, p):
    """R_enu<-flu = P Rz(psi) Ry(theta) Rx(phi) F, with the textbook NED/FRD matrices."""
    ps, th, ph = (math.radians(v) for v in (h, p, r))
    rz = np.array([[math.cos(ps), -math.sin(ps), 0], [math.sin(ps), math.cos(ps), 0], [0, 0, 1]])
    ry = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0], [-math.sin(th), 0, math.cos(th)]])
    rx = np.array([[1, 0, 0], [0, math.cos(ph), -math.sin(ph)], [0, math.sin(ph), math.cos(ph)]])
    swap = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    flip = np.diag([1, -1, -1])
    np.testing.assert_allclose(matrix(hpr_to_quaternion(h, r, p)), swap @ rz @ ry @ rx @ flip, atol=1e-12)


@given(st.floats(-720.0, 720.0), st.floats(-180.0, 180.0), st.floats(-90.0, 90.0))
def test_same_as_scipy_intrinsic_zyx(h, r, p):
    q = hpr_to_quaternion(h, r, p)
    ref = Rotation.from_euler("ZYX", [90.0 - h, -p, r], degrees=True).as_quat(scalar_first=True)
    assert q[0] >= 0.0
    assert abs(float(np.dot(q, ref))) == pytest.approx(1.0, abs=1e-12)  # same rotation, up to sign
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)


@given(
    st.floats(0.0, 360.0, exclude_max=True),
    st.floats(-179.0, 179.0),
    st.floats(-89.0, 89.0),
)
def test_hpr_round_trip_away_from_gimbal_lock(h, r, p):
    h2, r2, p2 = (float(v) for v in quaternion_to_hpr(hpr_to_quaternion(h, r, p)))
    assert abs((h2 - h + 180.0) % 360.0 - 180.0) < 1e-9
    assert abs(r2 - r) < 1e-9
    assert abs(p2 - p) < 1e-9
    assert 0.0 <= h2 < 360.0


quaternions = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
    lambda q: math.fsum(v * v for v in q) > 1e-6
)


@given(quaternions)
def test_quaternion_round_trip_any_rotation(q):
    h, r, p = quaternion_to_hpr(q)
    assert 0.0 <= float(h) < 360.0 and -180.0 <= float(r) <= 180.0 and -90.0 <= float(p) <= 90.0
    np.testing.assert_allclose(matrix(hpr_to_quaternion(h, r, p)), matrix(np.array(q) / np.linalg.norm(q)), atol=1e-9)


@pytest.mark.parametrize("pitch", [90.0, -90.0])
def test_gimbal_lock_puts_rotation_in_heading(pitch):
    q = hpr_to_quaternion(200.0, 10.0, pitch)
    h, r, p = (float(v) for v in quaternion_to_hpr(q))
    assert r == 0.0
    assert abs(p) == pytest.approx(90.0, abs=1e-6)
    np.testing.assert_allclose(matrix(hpr_to_quaternion(h, r, p)), matrix(q), atol=1e-9)
    # Yaw and roll about the same (vertical) axis: 200 - 10 at +90, 200 + 10 at -90.
    assert h == pytest.approx(190.0 if pitch > 0 else 210.0, abs=1e-6)


def test_vectorised_and_validated():
    q = hpr_to_quaternion([0.0, 90.0], [[0.0], [10.0]], 5.0)
    assert q.shape == (2, 2, 4)
    h, r, p = quaternion_to_hpr(q)
    assert h.shape == (2, 2)
    np.testing.assert_allclose(h, [[0.0, 90.0], [0.0, 90.0]], atol=1e-9)
    with pytest.raises(InputError, match="^roll: must be finite"):
        hpr_to_quaternion(0.0, float("nan"), 0.0)
    with pytest.raises(PoseError, match="^attitude: "):
        quaternion_to_hpr([0.0, 0.0, 0.0, 1e-12], field="attitude")
    assert wrap_heading(-1e-17) == 0.0
    assert wrap_heading(-90.0) == 270.0


# ---------------------------------------------------------------------------- GGA / RMC


def test_gga_exact_bytes():
    got = gga_sentence(T0, 46.5, 7.25, 1500.0, geoid_sep=48.0)
    assert got == with_checksum("GPGGA,123456.79,4630.0000000,N,00715.0000000,E,1,12,0.80,1452.000,M,48.000,M,,")


def test_gga_southern_western_and_options():
    got = gga_sentence(
        T0, -33.5, -70.75, 10.0, geoid_sep=-2.5, quality=4, sats=7, hdop=1.234, talker="GN", lat_lon_decimals=4
    )
    assert got == with_checksum("GNGGA,123456.79,3330.0000,S,07045.0000,W,4,07,1.23,12.500,M,-2.500,M,,")


def test_gga_without_fix_has_empty_position():
    got = gga_sentence(T0, None, None, None, quality=0, sats=0)
    assert got == with_checksum("GPGGA,123456.79,,,,,0,00,0.80,,,,,,")


def test_rmc_exact_bytes_with_velocity():
    got = rmc_sentence(T0, 46.5, 7.25, velocity_enu=(0.0, -2.0, 0.3))
    knots = 2.0 * 3600.0 / 1852.0
    assert got == with_checksum(f"GPRMC,123456.79,A,4630.0000000,N,00715.0000000,E,{knots:.3f},180.00,010324,,,A")


def test_rmc_invalid_and_no_course():
    got = rmc_sentence(T0, None, None, valid=False, speed_knots=0.0)
    assert got == with_checksum("GPRMC,123456.79,V,,,,,0.000,,010324,,,N")


def test_gps_sentences_is_rmc_then_gga():
    out = gps_sentences(T0, 1.0, 2.0, 3.0, quality=2)
    rmc, gga, tail = out.split(b"\r\n")
    assert tail == b""
    assert gga.startswith(b"$GPGGA,123456.79,0100.0000000,N,00200.0000000,E,2,")
    assert rmc.startswith(b"$GPRMC,123456.79,A,") and rmc.endswith(b",D*" + rmc[-2:])


def test_time_is_rounded_before_the_date_is_taken():
    t = datetime(2024, 12, 31, 23, 59, 59, 995000, tzinfo=UTC)
    rmc = rmc_sentence(t, 0.0, 0.0)
    assert rmc.split(b",")[1] == b"000000.00"
    assert rmc.split(b",")[9] == b"010125"  # 1 January 2025
    assert rmc_sentence(t - timedelta(microseconds=1), 0.0, 0.0).split(b",")[1:10:8] == [b"235959.99", b"311224"]


def test_naive_and_other_zone_datetimes():
    naive = datetime(2024, 3, 1, 12, 34, 56, 789000)
    assert gga_sentence(naive, 0.0, 0.0, 0.0) == gga_sentence(T0, 0.0, 0.0, 0.0)
    cet = T0.astimezone(timezone(timedelta(hours=1)))
    assert rmc_sentence(cet, 0.0, 0.0) == rmc_sentence(T0, 0.0, 0.0)


def test_latitude_rounding_never_prints_60_minutes():
    got = gga_sentence(T0, 44.99999999999, 179.999999999999, 0.0)
    assert b",4500.0000000,N,18000.0000000,E," in got
    tiny_south = gga_sentence(T0, -1e-12, -1e-12, 0.0)
    assert b",0000.0000000,N,00000.0000000,E," in tiny_south


def test_speed_course_from_enu():
    assert speed_course_from_enu(0.0, 0.0) == (0.0, None)
    s, c = speed_course_from_enu(1.0, 0.0)
    assert (s, c) == (pytest.approx(1.9438444924406046, abs=1e-15), 90.0)
    assert speed_course_from_enu(-1.0, 0.0)[1] == 270.0
    assert speed_course_from_enu(0.0, -1.0)[1] == 180.0
    assert speed_course_from_enu(1.0, 1.0)[1] == pytest.approx(45.0, abs=1e-12)
    assert KNOTS_PER_MPS == 3600.0 / 1852.0


def test_course_near_360_wraps_to_zero():
    got = rmc_sentence(T0, 0.0, 0.0, speed_knots=1.0, course=359.996)
    assert got.split(b",")[8] == b"0.00"


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: gga_sentence(T0, 91.0, 0.0, 0.0), "^lat: "),
        (lambda: gga_sentence(T0, 0.0, -180.5, 0.0), "^lon: "),
        (lambda: gga_sentence(T0, 0.0, None, 0.0), "^lat/lon: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, float("inf")), "^alt: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, 0.0, quality=9), "^quality: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, 0.0, sats=100), "^sats: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, 0.0, hdop=-1.0), "^hdop: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, 0.0, talker="gp"), "^talker: "),
        (lambda: gga_sentence("2024-03-01", 0.0, 0.0, 0.0), "^utc: "),
        (lambda: gga_sentence(T0, 0.0, 0.0, 0.0, lat_lon_decimals=12), "^lat_lon_decimals: "),
        (lambda: rmc_sentence(T0, 0.0, 0.0, mode="X"), "^mode: "),
        (lambda: rmc_sentence(T0, 0.0, 0.0, speed_knots=-1.0), "^speed_knots: "),
        (lambda: rmc_sentence(T0, 0.0, 0.0, velocity_enu=(1.0,)), "^velocity_enu: "),
        (lambda: rmc_sentence(T0, 0.0, 0.0, velocity_enu=(1.0, float("nan"))), "^velocity.north: "),
        (lambda: pashr_sentence(T0, float("nan"), 0.0, 0.0), "^heading: "),
        (lambda: pashr_sentence(T0, 0.0, 0.0, 0.0, roll_accuracy=-0.1), "^roll_accuracy: "),
        (lambda: pashr_sentence(T0, 0.0, 0.0, 0.0, ins_status=10), "^ins_status: "),
        (lambda: pashr_from_quaternion(T0, [0.0, 0.0, 0.0, 0.0]), "^orientation: "),
        (lambda: pashr_from_quaternion(T0, [[1.0, 0.0, 0.0, 0.0]]), "^orientation: "),
    ],
)
def test_bad_arguments_name_the_field(call, message):
    with pytest.raises(InputError, match=message):
        call()


# ---------------------------------------------------------------------------- PASHR


PASHR_LAYOUT = re.compile(
    rb"\$PASHR,\d{6}\.\d{3},\d{3}\.\d{2},T,[+-]\d{2,3}\.\d{2},[+-]\d{2}\.\d{2},[+-]\d{2,}\.\d{2},"
    rb"(\d+\.\d{3})?,(\d+\.\d{3})?,(\d+\.\d{3})?,\d,\d\*[0-9A-F]{2}\r\n\Z"
)


def test_pashr_exact_bytes_like_oxts():
    # The first $PASHR of gpsd's rst39.log (an OxTS unit), regenerated.
    got = pashr_sentence(
        datetime(2014, 2, 19, 20, 41, 32, tzinfo=UTC), 10.51, 0.39, -0.79, heave=-0.84,
        roll_accuracy=0.151, pitch_accuracy=0.075, heading_accuracy=0.555, gps_quality=1, ins_status=0,
    )
    assert got == b"$PASHR,204132.000,010.51,T,+00.39,-00.79,-00.84,0.151,0.075,0.555,1,0*03\r\n"


def test_pashr_heading_wraps_and_signs():
    got = pashr_sentence(T0, 359.996, -123.456, 0.004, roll_accuracy=None)
    assert got.startswith(b"$PASHR,123456.789,000.00,T,-123.46,+00.00,+00.00,,0.050,0.100,1,1*")
    assert PASHR_LAYOUT.match(got)
    assert pashr_sentence(T0, -90.0, 0.0, 0.0).split(b",")[2] == b"270.00"


def test_pashr_from_quaternion_identity_is_heading_90():
    got = pashr_from_quaternion(T0, [1.0, 0.0, 0.0, 0.0])
    assert got.split(b",")[2:6] == [b"090.00", b"T", b"+00.00", b"+00.00"]


def test_pashr_batch_is_the_same_bytes():
    rng = np.random.default_rng(5)
    q = rng.normal(size=(50, 4))
    times = [T0 + timedelta(seconds=0.01 * i) for i in range(50)]
    expected = b"".join(pashr_from_quaternion(t, qi, heave=0.5) for t, qi in zip(times, q))
    assert pashr_from_quaternions(times, q, heave=0.5) == expected
    assert pashr_from_quaternions([], np.empty((0, 4))) == b""
    with pytest.raises(PoseError, match="^orientation: needs shape"):
        pashr_from_quaternions(times[:2], q)


@pytest.mark.parametrize(
    "sentence",
    [
        lambda: gga_sentence(T0, 46.5, 7.25, 1500.0),
        lambda: rmc_sentence(T0, 46.5, 7.25, speed_knots=3.0, course=12.0),
        lambda: pashr_sentence(T0, 1.0, 2.0, 3.0),
    ],
)
def test_pynmeagps_accepts_what_we_generate(sentence):
    raw = sentence()
    msg = NMEAReader.parse(raw, validate=VALCKSUM | VALMSGID)
    assert msg is not None
    assert raw.endswith(b"\r\n") and raw.count(b"$") == 1


@given(
    st.datetimes(datetime(2000, 1, 1), datetime(2099, 12, 31), timezones=st.just(UTC)),
    st.floats(0.0, 360.0, exclude_max=True),
    st.floats(-180.0, 180.0),
    st.floats(-90.0, 90.0),
)
def test_pashr_always_matches_the_layout(t, h, r, p):
    assert PASHR_LAYOUT.match(pashr_sentence(t, h, r, p))


@given(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6))
def test_course_is_a_compass_angle(ve, vn):
    assume(math.hypot(ve, vn) > 0.0)
    speed, course = speed_course_from_enu(ve, vn)
    assert 0.0 <= course < 360.0
    assert speed == pytest.approx(math.hypot(ve, vn) * KNOTS_PER_MPS)
    c = math.radians(course)
    assert math.sin(c) * vn == pytest.approx(math.cos(c) * ve, abs=1e-9 * max(abs(ve), abs(vn)))
