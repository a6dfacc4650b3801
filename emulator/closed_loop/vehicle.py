"""Vehicles that carry a receiver: the paper's kinematic UAV (eq. 9) over a terrain.

Paper (Cacace, Mimmo, Marconi, ICRA 2020), section IV, eq. 9::

    d/dt p_r = V                      velocity-commanded, kinematic
    y_s      = L_z p_r - S(L_xy p_r) + v     range sensor: height above terrain + white noise
    L_z p_r >= S(L_xy p_r)            the vehicle never goes below the terrain

``S`` is the terrain (snow surface) elevation: :class:`FlatTerrain` (default, elevation 0)
or a DEM grid file (:class:`GridTerrain`, bilinear). Positions are world ENU metres
(BRIEF 2). The vehicle flies level: its attitude is a yaw about world z only, so the
receiver's x_r points along the heading (yaw 0 = east, counter-clockwise positive).

The scene table ``[receiver.vehicle]`` is parsed here (:func:`parse_vehicle`: the struct
:class:`VehicleTable` of :mod:`emulator.schema` types, as the rest of the scene).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from emulator.cli_types import BAUD_LIMITS
from emulator.files import read_regular
from emulator.scene.tables import MAX_VEHICLE_COORD_M, VEHICLE_LIMITS, TableReader
from emulator.schema import Int, Number, Strict, Text, Vector2, Vector3

CONTROLLERS = ("flux", "receiver_only", "external_mavlink")
MAX_DEM_BYTES = 256 << 20  #: largest terrain file read (bytes; a 4000 x 4000 float64 grid is 128 MB)


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
        lines starting with ``#`` ignored). Row 0 is the southern edge (y = origin y). Only a
        regular file of at most :data:`MAX_DEM_BYTES` is read (:class:`~emulator.files.FileRefused`)."""
        path = Path(path)
        data = read_regular(path, MAX_DEM_BYTES, "terrain file")  # (a FIFO would block for ever)
        if path.suffix.lower() == ".npy":
            z = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            lines = [line for line in csv.reader(data.decode("utf-8").splitlines()) if line]
            rows = [[float(v) for v in line] for line in lines if not line[0].lstrip().startswith("#")]
            if len({len(r) for r in rows}) > 1:
                raise ValueError("rows of the terrain CSV have different lengths")
            z = np.array(rows, dtype=np.float64)
        return cls(z, float(origin[0]), float(origin[1]), float(spacing[0]), float(spacing[1]))

    def height(self, x: float, y: float) -> float:
        ny, nx = self.z.shape
        fx = min(max((x - self.x0) / self.dx, 0.0), nx - 1.0)
        fy = min(max((y - self.y0) / self.dy, 0.0), ny - 1.0)
        i = min(int(fx), nx - 2)
        j = min(int(fy), ny - 2)
        tx, ty = fx - i, fy - j
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

    def __init__(self, terrain: Terrain, start: tuple[float, float], start_height: float,
                 yaw_deg: float = 0.0, v_max: float = 1.0, v_z_max: float = 2.0, range_sigma_m: float = 0.0,
                 rng: np.random.Generator | None = None) -> None:
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


def _limited(key: str, positive: bool = True):
    """A number of ``[receiver.vehicle]`` within :data:`VEHICLE_LIMITS` (``positive``: > 0)."""
    lo, hi = VEHICLE_LIMITS[key]
    return Number(lo, hi, positive=positive and lo == 0.0)


Coord = Number(-MAX_VEHICLE_COORD_M, MAX_VEHICLE_COORD_M, unit="m")
_D = VehicleSpec()


class VehicleTable(Strict):
    """``[receiver.vehicle]`` as written: every key, its type and range (emulator.schema)."""

    kind: Literal["uav"] = "uav"
    controller: Literal[CONTROLLERS] = "flux"
    start: tuple[Coord, Coord] = _D.start
    start_height: _limited("start_height", False) | None = None
    yaw: _limited("yaw") = 0.0
    v_max: _limited("v_max") = _D.v_max
    v_z_max: _limited("v_z_max") = _D.v_z_max
    r_s: _limited("r_s") = _D.r_s
    k_c: _limited("k_c") = _D.k_c
    k_z: _limited("k_z") = _D.k_z
    control_rate_hz: _limited("control_rate_hz") = _D.control_rate_hz
    range_sigma_m: _limited("range_sigma_m", False) = _D.range_sigma_m
    terrain: Text(".", 'flat or the path of a DEM grid file (.npy or .csv)') = "flat"
    terrain_height: _limited("terrain_height") | None = None
    terrain_origin: Vector2 | None = None
    terrain_spacing: Vector2 | None = None
    search_area: tuple[Coord, Coord, Coord, Coord] | None = None
    strip_width: _limited("strip_width") = _D.strip_width
    v_stop: _limited("v_stop") = _D.v_stop
    v_fine: _limited("v_fine") = _D.v_fine
    flux_reverse: bool = False
    mavlink: Text(".", "a pymavlink connection string (udpin:HOST:PORT, /dev/ttyUSB0, ...)") | None = None
    mavlink_origin: Vector3 | None = None
    mavlink_baud: Int(*BAUD_LIMITS) | None = None


def parse_vehicle(rd: TableReader, data: Any, path: str, scene_dir: Path | None) -> VehicleSpec:
    """Validate a ``vehicle`` table with the scene's reader ``rd`` (its file, its rules)."""
    v: VehicleTable = rd.convert(data, VehicleTable, path)
    mavlink = {"mavlink": v.mavlink, "mavlink_origin": v.mavlink_origin, "mavlink_baud": v.mavlink_baud}
    if v.controller != "external_mavlink":
        for key in sorted(k for k, value in mavlink.items() if value is not None):
            raise rd.fail(f"{path}.{key}", 'only with controller = "external_mavlink"')
    if v.search_area is not None and not (v.search_area[2] > v.search_area[0] and v.search_area[3] > v.search_area[1]):
        raise rd.fail(f"{path}.search_area", "expected [xmin, ymin, xmax, ymax] with xmax > xmin and ymax > ymin")
    terrain = _terrain(rd, v, path, scene_dir)
    external = v.controller == "external_mavlink"
    return VehicleSpec(
        **{k: getattr(v, k) for k in _SAME_KEYS}, yaw_deg=v.yaw, terrain=terrain,
        mavlink=(v.mavlink or "udpin:127.0.0.1:14550") if external else None,
        mavlink_origin=v.mavlink_origin or _D.mavlink_origin,
        mavlink_baud=v.mavlink_baud or _D.mavlink_baud,
    )


_SAME_KEYS = ("kind", "controller", "start", "start_height", "v_max", "v_z_max", "r_s", "k_c", "k_z", "control_rate_hz",
              "range_sigma_m", "search_area", "strip_width", "v_stop", "v_fine", "flux_reverse")


def _terrain(rd: TableReader, v: VehicleTable, path: str, scene_dir: Path | None) -> Terrain:
    p = lambda key: f"{path}.{key}"  # noqa: E731
    if v.terrain == "flat":
        for key in ("terrain_origin", "terrain_spacing"):
            if getattr(v, key) is not None:
                raise rd.fail(p(key), "only with a DEM terrain file")
        return FlatTerrain(v.terrain_height or 0.0)
    if v.terrain_height is not None:
        raise rd.fail(p("terrain_height"), 'only with terrain = "flat" (a DEM gives the heights)')
    for key in ("terrain_origin", "terrain_spacing"):
        if getattr(v, key) is None:
            raise rd.fail(p(key), f"missing: a DEM file needs {key} = [x, y] (metres)")
    if not (v.terrain_spacing[0] > 0 and v.terrain_spacing[1] > 0):
        raise rd.fail(p("terrain_spacing"), "both spacings must be > 0")
    file = Path(v.terrain)
    if not file.is_absolute() and scene_dir is not None:
        file = scene_dir / file
    if file.suffix.lower() not in (".npy", ".csv"):
        raise rd.fail(p("terrain"), f"a DEM file must be .npy or .csv, got {v.terrain!r}")
    try:
        return GridTerrain.load(file, list(v.terrain_origin), list(v.terrain_spacing))
    except (ValueError, EOFError) as exc:  # (FileRefused: its reason, not the path; EOFError: an empty .npy)
        raise rd.fail(p("terrain"), f"{str(file)!r}: {getattr(exc, 'reason', exc)}") from None
