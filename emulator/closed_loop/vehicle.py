"""Vehicles that carry a receiver: the paper's kinematic UAV (eq. 9) over a terrain.

Paper (Cacace, Mimmo, Marconi, ICRA 2020), section IV, eq. 9::

    d/dt p_r = V                      velocity-commanded, kinematic
    y_s      = L_z p_r - S(L_xy p_r) + v     range sensor: height above terrain + white noise
    L_z p_r >= S(L_xy p_r)            the vehicle never goes below the terrain

``S`` is the terrain (snow surface) elevation: :class:`FlatTerrain` (default, elevation 0)
or a DEM grid file (:class:`GridTerrain`, bilinear). Positions are world ENU metres
(BRIEF 2). The vehicle flies level: its attitude is a yaw about world z only, so the
receiver's x_r points along the heading (yaw 0 = east, counter-clockwise positive).

The scene table ``[receiver.vehicle]`` is parsed here (:func:`parse_vehicle`), with the
same strict rules as the rest of the scene (unknown keys are errors naming the key).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from emulator.cli_types import BAUD_LIMITS
from emulator.scene.limits import MAX_VEHICLE_COORD_M, VEHICLE_LIMITS
from emulator.scene.tables import TableReader

CONTROLLERS = ("flux", "receiver_only", "external_mavlink")


# --------------------------------------------------------------------------- terrain
@dataclass(frozen=True)
class FlatTerrain:
    """S(x, y) = elevation everywhere."""

    elevation: float = 0.0

    def height(self, x: float, y: float) -> float:
        return self.elevation

    def heights(self, x: NDArray, y: NDArray) -> NDArray[np.float64]:
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, self.elevation)


@dataclass(frozen=True, eq=False)
class GridTerrain:
    """A DEM: ``z[j, i]`` is the elevation at (x0 + i*dx, y0 + j*dy) (row 0 = south,
    column 0 = west). Bilinear between nodes; outside the grid the edge is held
    (coordinates are clamped to the grid), so S is defined everywhere and continuous."""

    z: NDArray[np.float64]
    x0: float
    y0: float
    dx: float
    dy: float

    def __post_init__(self) -> None:
        z = np.asarray(self.z, dtype=np.float64)
        if z.ndim != 2 or z.shape[0] < 2 or z.shape[1] < 2:
            raise ValueError(f"a terrain grid needs at least 2 x 2 elevations, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("terrain grid has a non-finite elevation")
        if not (self.dx > 0 and self.dy > 0):
            raise ValueError("terrain spacing must be > 0")
        object.__setattr__(self, "z", z)
        # Plain nested lists for the scalar path: indexing them is ~10x faster than numpy.
        object.__setattr__(self, "_rows", z.tolist())

    @classmethod
    def load(cls, path: str | Path, origin: tuple[float, float], spacing: tuple[float, float]) -> "GridTerrain":
        """Read ``.npy`` (a 2-D float array) or ``.csv`` (comma-separated rows of numbers,
        lines starting with ``#`` ignored). Row 0 is the southern edge (y = origin y)."""
        path = Path(path)
        if path.suffix.lower() == ".npy":
            z = np.load(path, allow_pickle=False)
        else:
            rows = []
            with path.open(newline="") as f:
                for line in csv.reader(f):
                    if not line or line[0].lstrip().startswith("#"):
                        continue
                    rows.append([float(v) for v in line])
            if len({len(r) for r in rows}) > 1:
                raise ValueError("rows of the terrain CSV have different lengths")
            z = np.array(rows, dtype=np.float64)
        return cls(z, float(origin[0]), float(origin[1]), float(spacing[0]), float(spacing[1]))

    def _cell(self, x: float, y: float) -> tuple[int, int, float, float]:
        ny, nx = self.z.shape
        fx = min(max((x - self.x0) / self.dx, 0.0), nx - 1.0)
        fy = min(max((y - self.y0) / self.dy, 0.0), ny - 1.0)
        i = min(int(fx), nx - 2)
        j = min(int(fy), ny - 2)
        return i, j, fx - i, fy - j

    def height(self, x: float, y: float) -> float:
        i, j, tx, ty = self._cell(x, y)
        r0, r1 = self._rows[j], self._rows[j + 1]
        a = r0[i] + tx * (r0[i + 1] - r0[i])
        b = r1[i] + tx * (r1[i + 1] - r1[i])
        return a + ty * (b - a)

    def heights(self, x: NDArray, y: NDArray) -> NDArray[np.float64]:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        ny, nx = self.z.shape
        fx = np.clip((x - self.x0) / self.dx, 0.0, nx - 1.0)
        fy = np.clip((y - self.y0) / self.dy, 0.0, ny - 1.0)
        i = np.minimum(fx.astype(np.int64), nx - 2)
        j = np.minimum(fy.astype(np.int64), ny - 2)
        tx, ty = fx - i, fy - j
        z = self.z
        a = z[j, i] + tx * (z[j, i + 1] - z[j, i])
        b = z[j + 1, i] + tx * (z[j + 1, i + 1] - z[j + 1, i])
        return a + ty * (b - a)


Terrain = FlatTerrain | GridTerrain


# --------------------------------------------------------------------------- the UAV
class RangeSensor:
    """y_s = z - S(x, y) + v, v ~ N(0, sigma^2) white (paper eq. 9), seeded."""

    BLOCK = 1024

    def __init__(self, terrain: Terrain, sigma_m: float, rng: np.random.Generator | None) -> None:
        self.terrain = terrain
        self.sigma = float(sigma_m)
        self._rng = rng if sigma_m > 0 else None
        self._buf: list[float] = []

    def read(self, x: float, y: float, z: float) -> float:
        value = z - self.terrain.height(x, y)
        if self._rng is not None:
            if not self._buf:
                self._buf = self.draw_block().tolist()[::-1]
            value += self._buf.pop()
        return value

    def draw_block(self) -> NDArray[np.float64]:
        """The next BLOCK noise values v (m), in reading order: readings draw in blocks,
        one numpy call per BLOCK readings (a batch loop draws the same blocks)."""
        return self._rng.standard_normal(self.BLOCK) * self.sigma


class UAV:
    """Kinematic UAV of paper eq. 9: ``step(v, dt)`` integrates p += V dt.

    The commanded horizontal speed is limited to ``v_max`` (the controllers already stay
    below it) and the vertical one to ``v_z_max``; after each step the constraint
    z >= S(x, y) holds (a step that would go below the terrain stops on it, counted in
    ``ground_contacts``). State is plain floats: one step costs about a microsecond.
    """

    def __init__(
        self,
        terrain: Terrain,
        start: tuple[float, float],
        start_height: float,
        yaw_deg: float = 0.0,
        v_max: float = 1.0,
        v_z_max: float = 2.0,
        range_sigma_m: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.terrain = terrain
        self.x, self.y = float(start[0]), float(start[1])
        self.z = terrain.height(self.x, self.y) + float(start_height)
        self.yaw = math.radians(yaw_deg)
        self.v_max = float(v_max)
        self.v_z_max = float(v_z_max)
        self.range = RangeSensor(terrain, range_sigma_m, rng)
        self.ground_contacts = 0

    @property
    def position(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.z)

    @property
    def orientation(self) -> tuple[float, float, float, float]:
        """[w, x, y, z]: a pure yaw (level flight), body x along the heading."""
        return (math.cos(self.yaw / 2.0), 0.0, 0.0, math.sin(self.yaw / 2.0))

    def height_reading(self) -> float:
        return self.range.read(self.x, self.y, self.z)

    def step(self, vx: float, vy: float, vz: float, dt: float) -> None:
        speed = math.hypot(vx, vy)
        if speed > self.v_max:
            k = self.v_max / speed
            vx, vy = vx * k, vy * k
        vz = min(max(vz, -self.v_z_max), self.v_z_max)
        self.x += vx * dt
        self.y += vy * dt
        self.z += vz * dt
        ground = self.terrain.height(self.x, self.y)
        if self.z < ground:
            self.z = ground
            self.ground_contacts += 1


# --------------------------------------------------------------------------- scene spec
@dataclass(frozen=True)
class VehicleSpec:
    """``[receiver.vehicle]``: what carries the receiver and what flies it.

    Lengths in metres, speeds in m/s, angles in degrees. ``r_s`` is the paper's height
    reference above the terrain (and the default "located" radius); ``k_c``, ``k_z`` its
    gains (eq. 10 and V_z = k_z (r_s - y_s)).
    """

    kind: str = "uav"
    controller: str = "flux"
    start: tuple[float, float] = (0.0, 0.0)
    start_height: float | None = None  # default: r_s
    yaw_deg: float = 0.0
    v_max: float = 1.0
    v_z_max: float = 2.0
    r_s: float = 1.0
    k_c: float = 0.2
    k_z: float = 1.0
    control_rate_hz: float = 10.0
    range_sigma_m: float = 0.0
    terrain: Terrain = FlatTerrain()
    terrain_source: str = "flat"
    # Signal search (both search controllers): a lawnmower over this rectangle.
    search_area: tuple[float, float, float, float] | None = None  # xmin, ymin, xmax, ymax
    strip_width: float = 30.0
    # Controller details.
    v_stop: float = 0.02  # flux: located when |V_xy| < v_stop on 3 consecutive epochs
    flux_reverse: bool = False  # flux: follow -h instead while |h| keeps falling (not in the paper)
    v_fine: float = 0.25  # receiver_only: bracketing speed
    # External loop.
    mavlink: str | None = None
    mavlink_origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mavlink_baud: int = 57600  # a serial telemetry link only (radios: 57600; USB: any)

    @property
    def height_start(self) -> float:
        return self.r_s if self.start_height is None else self.start_height


_VEHICLE_KEYS = {
    "kind", "controller", "start", "start_height", "yaw", "v_max", "v_z_max", "r_s", "k_c", "k_z",
    "control_rate_hz", "range_sigma_m", "terrain", "terrain_height", "terrain_origin", "terrain_spacing",
    "search_area", "strip_width", "v_stop", "v_fine", "flux_reverse", "mavlink", "mavlink_origin",
    "mavlink_baud",
}
_MAVLINK_ONLY = {"mavlink", "mavlink_origin", "mavlink_baud"}


def parse_vehicle(rd: TableReader, data: Any, path: str, scene_dir: Path | None) -> VehicleSpec:
    """Validate a ``vehicle`` table with the scene's reader ``rd`` (its file, its rules)."""
    if not isinstance(data, dict):
        raise rd.fail(path, "expected a table")
    rd.known_keys(data, path, _VEHICLE_KEYS)
    p = lambda key: f"{path}.{key}"  # noqa: E731
    kind = data.get("kind", "uav")
    if kind != "uav":
        raise rd.fail(p("kind"), f"unknown vehicle kind {kind!r} (known: uav)")
    controller = data.get("controller", "flux")
    if controller not in CONTROLLERS:
        raise rd.fail(p("controller"), f"unknown controller {controller!r} (known: {', '.join(CONTROLLERS)})")
    if controller != "external_mavlink":
        for key in sorted(_MAVLINK_ONLY & set(data)):
            raise rd.fail(p(key), 'only with controller = "external_mavlink"')
    d = VehicleSpec()
    num = lambda key, default, positive=False: rd.number(  # noqa: E731
        data, key, p(key), default, positive, limits=VEHICLE_LIMITS.get(key)
    )
    nonneg = lambda key, default: _non_negative(rd, num(key, default), p(key))  # noqa: E731

    start = _coords(rd, rd.vector(data["start"], p("start"), 2), p("start")) if "start" in data else d.start
    terrain, source = _terrain(rd, data, path, scene_dir)
    area = None
    if "search_area" in data:
        area = _coords(rd, rd.vector(data["search_area"], p("search_area"), 4), p("search_area"))
        if not (area[2] > area[0] and area[3] > area[1]):
            raise rd.fail(p("search_area"), "expected [xmin, ymin, xmax, ymax] with xmax > xmin and ymax > ymin")
    mavlink = None
    origin = d.mavlink_origin
    if controller == "external_mavlink":
        mavlink = data.get("mavlink", "udpin:127.0.0.1:14550")
        if not isinstance(mavlink, str) or not mavlink:
            raise rd.fail(p("mavlink"), "expected a pymavlink connection string (udpin:HOST:PORT, /dev/ttyUSB0, ...)")
        if "mavlink_origin" in data:
            origin = tuple(rd.vector(data["mavlink_origin"], p("mavlink_origin"), 3))
        baud = rd.integer(data, "mavlink_baud", p("mavlink_baud"), d.mavlink_baud, *BAUD_LIMITS)
    else:
        baud = d.mavlink_baud
    spec = VehicleSpec(
        kind=kind,
        controller=controller,
        start=(float(start[0]), float(start[1])),
        start_height=nonneg("start_height", None) if "start_height" in data else None,
        yaw_deg=num("yaw", 0.0),
        v_max=num("v_max", d.v_max, True),
        v_z_max=num("v_z_max", d.v_z_max, True),
        r_s=num("r_s", d.r_s, True),
        k_c=num("k_c", d.k_c, True),
        k_z=num("k_z", d.k_z, True),
        control_rate_hz=num("control_rate_hz", d.control_rate_hz, True),
        range_sigma_m=nonneg("range_sigma_m", d.range_sigma_m),
        terrain=terrain,
        terrain_source=source,
        search_area=area,
        strip_width=num("strip_width", d.strip_width, True),
        v_stop=num("v_stop", d.v_stop, True),
        v_fine=num("v_fine", d.v_fine, True),
        flux_reverse=rd.boolean(data, "flux_reverse", p("flux_reverse"), False),
        mavlink=mavlink,
        mavlink_origin=tuple(float(v) for v in origin),
        mavlink_baud=baud,
    )
    return spec


def _coords(rd: TableReader, values: list[float], path: str) -> tuple[float, ...]:
    for i, v in enumerate(values):
        if abs(v) > MAX_VEHICLE_COORD_M:
            raise rd.fail(f"{path}[{i}]", f"must be within [{-MAX_VEHICLE_COORD_M:g}, {MAX_VEHICLE_COORD_M:g}] m, got {v:g}")
    return tuple(values)


def _non_negative(rd: TableReader, value: float, path: str) -> float:
    if value < 0:
        raise rd.fail(path, f"must be >= 0, got {value:g}")
    return value


def _terrain(rd: TableReader, data: dict, path: str, scene_dir: Path | None) -> tuple[Terrain, str]:
    p = lambda key: f"{path}.{key}"  # noqa: E731
    name = data.get("terrain", "flat")
    if not isinstance(name, str) or not name:
        raise rd.fail(p("terrain"), 'expected "flat" or the path of a DEM grid file (.npy or .csv)')
    if name == "flat":
        for key in ("terrain_origin", "terrain_spacing"):
            if key in data:
                raise rd.fail(p(key), "only with a DEM terrain file")
        height = rd.number(data, "terrain_height", p("terrain_height"), 0.0, limits=VEHICLE_LIMITS["terrain_height"])
        return FlatTerrain(height), "flat"
    if "terrain_height" in data:
        raise rd.fail(p("terrain_height"), 'only with terrain = "flat" (a DEM gives the heights)')
    for key in ("terrain_origin", "terrain_spacing"):
        if key not in data:
            raise rd.fail(p(key), f"missing: a DEM file needs {key} = [x, y] (metres)")
    origin = rd.vector(data["terrain_origin"], p("terrain_origin"), 2)
    spacing = rd.vector(data["terrain_spacing"], p("terrain_spacing"), 2)
    if not (spacing[0] > 0 and spacing[1] > 0):
        raise rd.fail(p("terrain_spacing"), "both spacings must be > 0")
    file = Path(name)
    if not file.is_absolute() and scene_dir is not None:
        file = scene_dir / file
    if file.suffix.lower() not in (".npy", ".csv"):
        raise rd.fail(p("terrain"), f"a DEM file must be .npy or .csv, got {name!r}")
    try:
        return GridTerrain.load(file, origin, spacing), str(file)
    except OSError as exc:
        raise rd.fail(p("terrain"), f"cannot read {str(file)!r}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise rd.fail(p("terrain"), f"{str(file)!r}: {exc}") from None
