"""WGS-84 geodetic / ECEF / ENU: exact values from the ellipsoid formulas, round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulator.frames.geodesy import (
    WGS84_A,
    WGS84_B,
    GeodeticError,
    Origin,
    ecef_to_enu,
    ecef_to_geodetic,
    enu_to_ecef,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)
from firmware_proto.errors import InputError

# The ellipsoid, written out again here so the tests do not lean on the module's constants.
A = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)

lats = st.floats(-90.0, 90.0, allow_nan=False)
lons = st.floats(-180.0, 180.0, allow_nan=False)
alts = st.floats(-5.0e6, 4.0e7, allow_nan=False)
near_alts = st.floats(-1.0e4, 1.0e4, allow_nan=False)
local = st.floats(-1.0e5, 1.0e5, allow_nan=False)


def meridian_radius(phi: float) -> float:
    """M(phi) = a (1 - e^2) / (1 - e^2 sin^2 phi)^(3/2), metres per radian of latitude."""
    s = math.sin(phi)
    return A * (1.0 - E2) / (1.0 - E2 * s * s) ** 1.5


# ---------------------------------------------------------------------------- constants


def test_constants_are_wgs84():
    assert WGS84_A == 6378137.0
    assert WGS84_B == pytest.approx(6356752.314245179, abs=1e-9)


# ---------------------------------------------------------------------------- known values


def test_equator_prime_meridian_is_semi_major_axis():
    x, y, z = geodetic_to_ecef(0.0, 0.0, 0.0)
    assert (float(x), float(y), float(z)) == (A, 0.0, 0.0)


def test_equator_90_east_with_height():
    x, y, z = geodetic_to_ecef(0.0, 90.0, 1000.0)
    assert float(x) == pytest.approx(0.0, abs=1e-9)
    assert float(y) == A + 1000.0
    assert float(z) == 0.0


@pytest.mark.parametrize("lat", [90.0, -90.0])
def test_poles_are_semi_minor_axis(lat):
    x, y, z = geodetic_to_ecef(lat, 123.0, 250.0)
    assert abs(float(x)) < 1e-9 and abs(float(y)) < 1e-9
    assert float(z) == pytest.approx(math.copysign(A * (1.0 - F) + 250.0, lat), abs=1e-8)
    back_lat, _, back_alt = ecef_to_geodetic(x, y, z)
    assert float(back_lat) == lat
    assert float(back_alt) == pytest.approx(250.0, abs=1e-8)


def test_polar_axis_gives_exact_pole():
    lat, lon, alt = ecef_to_geodetic(0.0, 0.0, -(A * (1.0 - F)) - 10.0)
    assert (float(lat), float(lon)) == (-90.0, 0.0)
    assert float(alt) == pytest.approx(10.0, abs=1e-8)


def test_45_north_by_hand():
    """ECEF of (45 N, 0 E, 0 m) from N = a / sqrt(1 - e^2 sin^2 phi)."""
    s = c = math.sqrt(0.5)
    n = A / math.sqrt(1.0 - E2 * s * s)
    x, y, z = geodetic_to_ecef(45.0, 0.0, 0.0)
    assert float(x) == pytest.approx(n * c, abs=1e-8)
    assert float(y) == 0.0
    assert float(z) == pytest.approx(n * (1.0 - E2) * s, abs=1e-8)
    # The numbers themselves, so a wrong ellipsoid cannot hide in both sides.
    assert float(x) == pytest.approx(4517590.878848567, abs=1e-6)
    assert float(z) == pytest.approx(4487348.408865919, abs=1e-6)


def test_origin_maps_to_zero_exactly():
    o = Origin(46.5, 7.25, 1234.5)
    e, n, u = geodetic_to_enu(o.lat, o.lon, o.alt, o)
    assert (float(e), float(n), float(u)) == (0.0, 0.0, 0.0)
    lat, lon, alt = enu_to_geodetic(0.0, 0.0, 0.0, o)
    assert float(lat) == pytest.approx(46.5, abs=1e-12)
    assert float(lon) == pytest.approx(7.25, abs=1e-12)
    assert float(alt) == pytest.approx(1234.5, abs=1e-8)


def test_1e5_deg_north_at_45n():
    """1e-5 deg of latitude at 45 N is M(phi_mid) * dphi = 1.1113177751 m north.

    The chord of the meridian arc equals the arc to ~1e-20 m at this length; the point
    drops below the tangent plane by s^2 / (2 M) = 9.7e-8 m. Tolerances are the float64
    resolution of the ECEF difference (~1e-9 m), not the size of any approximation.
    """
    o = Origin(45.0, 7.0, 0.0)
    e, n, u = geodetic_to_enu(45.0 + 1e-5, 7.0, 0.0, o)
    dphi = math.radians(1e-5)
    arc = meridian_radius(math.radians(45.0 + 0.5e-5)) * dphi
    assert arc == pytest.approx(1.111317775, abs=1e-9)
    assert float(n) == pytest.approx(arc, abs=3e-9)
    assert float(e) == pytest.approx(0.0, abs=3e-9)
    assert float(u) == pytest.approx(-(arc**2) / (2.0 * meridian_radius(math.radians(45.0))), abs=3e-9)
    assert float(u) < -9e-8


def test_1e5_deg_east_on_equator_is_a_chord():
    o = Origin(0.0, 0.0, 0.0)
    d = math.radians(1e-5)
    e, n, u = geodetic_to_enu(0.0, 1e-5, 0.0, o)
    assert float(e) == pytest.approx(A * math.sin(d), abs=1e-9)
    assert float(n) == 0.0
    assert float(u) == pytest.approx(A * (math.cos(d) - 1.0), abs=1e-9)


def test_enu_axes_point_east_north_up():
    o = Origin(-33.9, 18.4, 10.0)
    e, n, u = enu_to_ecef([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], o)
    d = np.stack([e, n, u], axis=1) - o.ecef  # rows: ECEF of the unit steps
    lat, lon = math.radians(o.lat), math.radians(o.lon)
    east = [-math.sin(lon), math.cos(lon), 0.0]
    north = [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
    up = [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]
    np.testing.assert_allclose(d, [east, north, up], atol=1e-9)
    r = o.enu_rotation
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)


def test_vectorised_shapes_and_dtypes():
    lat = np.array([[0.0], [45.0]])
    lon = np.array([0.0, 90.0, -179.5])
    x, y, z = geodetic_to_ecef(lat, lon, 0.0)
    assert x.shape == y.shape == z.shape == (2, 3)
    assert x.dtype == np.float64
    lat2, lon2, alt2 = ecef_to_geodetic(x, y, z)
    np.testing.assert_allclose(lat2, np.broadcast_to(lat, (2, 3)), atol=1e-12)
    np.testing.assert_allclose(lon2, np.broadcast_to(lon, (2, 3)), atol=1e-12)
    s = geodetic_to_ecef(10, 20, 30)
    assert all(v.shape == () for v in s)
    o = Origin(1.0, 2.0)
    e, n, u = ecef_to_enu(x, y, z, o)
    assert e.shape == (2, 3)
    float32 = geodetic_to_enu(np.float32(1.0), np.float32(2.0), np.float32(0.0), o)
    assert float32[0].dtype == np.float64


# ---------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"lat": 90.0000001, "lon": 0.0}, "origin.lat"),
        ({"lat": -91.0, "lon": 0.0}, "origin.lat"),
        ({"lat": float("nan"), "lon": 0.0}, "origin.lat"),
        ({"lat": 0.0, "lon": 180.5}, "origin.lon"),
        ({"lat": 0.0, "lon": float("-inf")}, "origin.lon"),
        ({"lat": 0.0, "lon": 0.0, "alt": float("inf")}, "origin.alt"),
        ({"lat": "45", "lon": 0.0}, "origin.lat"),
        ({"lat": 0.0, "lon": True}, "origin.lon"),
    ],
)
def test_origin_rejects_bad_fields_by_name(kwargs, field):
    with pytest.raises(GeodeticError) as info:
        Origin(**kwargs)
    assert isinstance(info.value, InputError)
    assert info.value.field == field
    assert str(info.value).startswith(field + ": ")


def test_origin_accepts_limits_and_ints():
    o = Origin(-90, 180, -400)
    assert (o.lat, o.lon, o.alt) == (-90.0, 180.0, -400.0)
    assert isinstance(o.lat, float)
    assert Origin(90.0, -180.0) == Origin(90, -180, 0)


@pytest.mark.parametrize(
    "args, field",
    [
        ((91.0, 0.0, 0.0), "lat"),
        ((0.0, -180.01, 0.0), "lon"),
        ((0.0, 0.0, float("nan")), "alt"),
        (([0.0, float("inf")], 0.0, 0.0), "lat"),
    ],
)
def test_geodetic_inputs_validated(args, field):
    with pytest.raises(GeodeticError) as info:
        geodetic_to_ecef(*args)
    assert info.value.field == field


def test_enu_inputs_must_be_finite():
    with pytest.raises(GeodeticError, match="^n: "):
        enu_to_geodetic(0.0, float("nan"), 0.0, Origin(0.0, 0.0))
    with pytest.raises(GeodeticError, match="^z: "):
        ecef_to_geodetic(1.0, 2.0, float("inf"))


# ---------------------------------------------------------------------------- round trips


def _lon_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@given(lats, lons, alts)
def test_geodetic_ecef_round_trip_whole_globe(lat, lon, alt):
    x, y, z = geodetic_to_ecef(lat, lon, alt)
    lat2, lon2, alt2 = (float(v) for v in ecef_to_geodetic(x, y, z))
    assert abs(lat2 - lat) < 1e-9
    assert abs(alt2 - alt) < 1e-6
    if abs(lat) < 89.9999:  # at the pole every longitude is the same point
        assert _lon_diff(lon2, lon) < 1e-9
    x2, y2, z2 = geodetic_to_ecef(lat2, lon2, alt2)
    assert math.dist((x, y, z), (x2, y2, z2)) < 1e-6


@given(lats, lons, near_alts, local, local, st.floats(-1.0e4, 1.0e4))
def test_enu_round_trip_within_100_km(lat0, lon0, alt0, e, n, u):
    o = Origin(lat0, lon0, alt0)
    lat, lon, alt = enu_to_geodetic(e, n, u, o)
    e2, n2, u2 = geodetic_to_enu(lat, lon, alt, o)
    assert math.dist((e, n, u), (float(e2), float(n2), float(u2))) < 1e-6


@given(lats, lons, near_alts, st.floats(-0.9, 0.9), st.floats(-0.9, 0.9), near_alts)
def test_geodetic_enu_round_trip_near_origin(lat0, lon0, alt0, dlat, dlon, alt):
    o = Origin(lat0, lon0, alt0)
    lat = min(90.0, max(-90.0, lat0 + dlat))
    lon = (lon0 + dlon + 180.0) % 360.0 - 180.0
    e, n, u = geodetic_to_enu(lat, lon, alt, o)
    lat2, lon2, alt2 = (float(v) for v in enu_to_geodetic(e, n, u, o))
    assert abs(lat2 - lat) < 1e-9
    assert abs(alt2 - alt) < 1e-6
    if abs(lat) < 89.9999:
        assert _lon_diff(lon2, lon) < 1e-9
