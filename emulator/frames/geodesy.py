"""WGS-84 geodetic <-> ECEF <-> local ENU, vectorised float64.

Units and frames
----------------
* Geodetic: latitude and longitude in degrees (north and east positive), altitude in
  metres above the WGS-84 ellipsoid (HAE, not above mean sea level).
* ECEF: earth-centred, earth-fixed Cartesian metres (x through lat 0 / lon 0, z through
  the north pole).
* ENU: the world frame of BRIEF section 2 -- metres east, north and up in the plane
  tangent to the ellipsoid at an :class:`Origin` (x east, y north, z up).

All functions accept scalars or arrays of any broadcastable shape and return a tuple of
three float64 arrays of the broadcast shape (0-d arrays for scalar inputs).

ECEF -> geodetic is Bowring's iteration, three steps, written with atan2 so the poles
and the equator need no special case: geodetic -> ECEF -> geodetic returns the latitude
to < 1e-9 deg and the height to < 1e-6 m for heights from -5,000 km to 40,000 km
(``tests/emulator/frames/test_geodesy.py``). The formulas and why: docs/emulator.md
"Geodesy".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import PoseError

# WGS-84 defining constants (NIMA TR8350.2) and the derived ones we use.
WGS84_A = 6378137.0  #: semi-major axis, m
WGS84_F = 1.0 / 298.257223563  #: flattening
WGS84_B = WGS84_A * (1.0 - WGS84_F)  #: semi-minor axis, m
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  #: first eccentricity squared
WGS84_EP2 = WGS84_E2 / (1.0 - WGS84_E2)  #: second eccentricity squared

_BOWRING_STEPS = 3

Vec3 = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


class GeodeticError(PoseError):
    """A geodetic coordinate that cannot be used; ``field`` names it (e.g. ``origin.lat``)."""


def finite_arrays(error: type[PoseError], /, **values: ArrayLike) -> list[NDArray[np.float64]]:
    """Each value as a float64 array; an ``error`` (a :class:`~firmware_proto.errors.PoseError`
    class, e.g. :class:`GeodeticError`) names the first one that is not finite numbers."""
    out = []
    for field, value in values.items():
        try:
            out.append(np.asarray(value, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise error(field, f"not a number: {value!r}") from exc
        if not np.all(np.isfinite(out[-1])):
            raise error(field, "must be finite")
    return out


@dataclass(frozen=True)
class Origin:
    """The geodetic point (degrees, degrees, metres HAE) at which a local ENU frame sits.

    Validated on construction: every field finite, ``lat`` in [-90, 90], ``lon`` in
    [-180, 180]; otherwise :class:`GeodeticError` (an ``InputError``) naming the field.
    """

    lat: float
    lon: float
    alt: float = 0.0

    def __post_init__(self) -> None:
        for name in ("lat", "lon", "alt"):
            raw = getattr(self, name)
            if isinstance(raw, bool) or not isinstance(raw, (int, float, np.integer, np.floating)):
                raise GeodeticError(f"origin.{name}", f"must be a number, got {raw!r}")
            value = float(raw)
            if not math.isfinite(value):
                raise GeodeticError(f"origin.{name}", "must be finite")
            object.__setattr__(self, name, value)
        if not -90.0 <= self.lat <= 90.0:
            raise GeodeticError("origin.lat", f"latitude {self.lat} is outside [-90, 90] degrees")
        if not -180.0 <= self.lon <= 180.0:
            raise GeodeticError("origin.lon", f"longitude {self.lon} is outside [-180, 180] degrees")

    @cached_property
    def ecef(self) -> NDArray[np.float64]:
        """The origin in ECEF metres, shape (3,)."""
        x, y, z = geodetic_to_ecef(self.lat, self.lon, self.alt)
        return np.array([x, y, z], dtype=np.float64)

    @cached_property
    def enu_rotation(self) -> NDArray[np.float64]:
        """R (3, 3) with ``enu = R @ (ecef - origin.ecef)``; rows are e, n, u in ECEF."""
        phi, lam = math.radians(self.lat), math.radians(self.lon)
        sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
        return np.array([[-sl, cl, 0.0],
                         [-sp * cl, -sp * sl, cp],
                         [cp * cl, cp * sl, sp]])


def geodetic_to_ecef(lat: ArrayLike, lon: ArrayLike, alt: ArrayLike) -> Vec3:
    """ECEF metres of geodetic (deg, deg, m HAE). Raises GeodeticError on bad input."""
    lat_a, lon_a, alt_a = finite_arrays(GeodeticError, lat=lat, lon=lon, alt=alt)
    if np.any(np.abs(lat_a) > 90.0):
        raise GeodeticError("lat", "latitude must be in [-90, 90] degrees")
    if np.any(np.abs(lon_a) > 180.0):
        raise GeodeticError("lon", "longitude must be in [-180, 180] degrees")
    phi = np.radians(lat_a)
    lam = np.radians(lon_a)
    sp, cp = np.sin(phi), np.cos(phi)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sp * sp)  # prime-vertical radius of curvature
    x = (n + alt_a) * cp * np.cos(lam)
    y = (n + alt_a) * cp * np.sin(lam)
    z = (n * (1.0 - WGS84_E2) + alt_a) * sp
    x, y, z = np.broadcast_arrays(x, y, z)
    return np.array(x, dtype=np.float64), np.array(y, dtype=np.float64), np.array(z, dtype=np.float64)


def ecef_to_geodetic(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> Vec3:
    """Geodetic (deg, deg, m HAE) of ECEF metres by Bowring's iteration (docs/emulator.md, "Geodesy").

    Longitude is in [-180, 180]; on the polar axis it is 0 (any value is correct there).
    """
    xa, ya, za = np.broadcast_arrays(*finite_arrays(GeodeticError, x=x, y=y, z=z))
    p = np.hypot(xa, ya)
    beta = np.arctan2(za, (1.0 - WGS84_F) * p)
    phi = beta
    for _ in range(_BOWRING_STEPS):
        sb, cb = np.sin(beta), np.cos(beta)
        phi = np.arctan2(za + WGS84_EP2 * WGS84_B * sb**3, p - WGS84_E2 * WGS84_A * cb**3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(phi), np.cos(phi))
    sp, cp = np.sin(phi), np.cos(phi)
    h = p * cp + za * sp - WGS84_A * np.sqrt(1.0 - WGS84_E2 * sp * sp)
    lon = np.degrees(np.arctan2(ya, xa))
    return np.array(np.degrees(phi)), np.array(lon), np.array(h)


def ecef_to_enu(x: ArrayLike, y: ArrayLike, z: ArrayLike, origin: Origin) -> Vec3:
    """ENU metres about ``origin`` of ECEF metres."""
    xa, ya, za = finite_arrays(GeodeticError, x=x, y=y, z=z)
    # Subtract first: both are ~6.4e6 m, so the difference is exact to ~1e-9 m and the
    # rotation then acts on small numbers.
    dx, dy, dz = xa - origin.ecef[0], ya - origin.ecef[1], za - origin.ecef[2]
    r = origin.enu_rotation
    e = r[0, 0] * dx + r[0, 1] * dy  # r[0, 2] is exactly 0
    n = r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz
    u = r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz
    e, n, u = np.broadcast_arrays(e, n, u)
    return np.array(e), np.array(n), np.array(u)


def enu_to_ecef(e: ArrayLike, n: ArrayLike, u: ArrayLike, origin: Origin) -> Vec3:
    """ECEF metres of ENU metres about ``origin``."""
    ea, na, ua = finite_arrays(GeodeticError, e=e, n=n, u=u)
    r = origin.enu_rotation  # orthonormal: the inverse is the transpose
    x = r[0, 0] * ea + r[1, 0] * na + r[2, 0] * ua + origin.ecef[0]
    y = r[0, 1] * ea + r[1, 1] * na + r[2, 1] * ua + origin.ecef[1]
    z = r[1, 2] * na + r[2, 2] * ua + origin.ecef[2]
    x, y, z = np.broadcast_arrays(x, y, z)
    return np.array(x), np.array(y), np.array(z)


def geodetic_to_enu(lat: ArrayLike, lon: ArrayLike, alt: ArrayLike, origin: Origin) -> Vec3:
    """ENU metres about ``origin`` of geodetic (deg, deg, m HAE)."""
    return ecef_to_enu(*geodetic_to_ecef(lat, lon, alt), origin)


def enu_to_geodetic(e: ArrayLike, n: ArrayLike, u: ArrayLike, origin: Origin) -> Vec3:
    """Geodetic (deg, deg, m HAE) of ENU metres about ``origin``."""
    return ecef_to_geodetic(*enu_to_ecef(e, n, u, origin))
