"""Strict typed access to decoded TOML tables, for scene files and the tables inside them.

Every value is checked for type, length and range, and the first problem raises
:class:`~firmware_proto.errors.SceneError` whose text is ``FILE: key.path: reason`` (one
line, naming the exact key). :mod:`emulator.scene.reader` reads whole scenes with it;
other parts of a scene (a vehicle table, :func:`emulator.closed_loop.vehicle.parse_vehicle`)
read their own table with the same rules through this public interface.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from firmware_proto.errors import PoseError, SceneError

from emulator.frames.rotation import normalize_quaternions
from emulator.frames.trajectory import IDENTITY, Trajectory
from emulator.scene.limits import MIN_WAYPOINT_DT_S

#: Stream rates a scene may ask for, Hz: one epoch per 1000 s up to 10 kHz.
RATE_LIMITS_HZ = (1e-3, 1e4)


class TableReader:
    """Typed access to a TOML table that reports errors as ``FILE: key.path: reason``."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, reason: str) -> SceneError:
        return SceneError(self.source, key, reason)

    def table(self, data: dict, key: str, path: str, allowed: set[str], required: bool = False) -> dict:
        value = data.get(key)
        if value is None:
            if required:
                raise self.fail(path, "missing table")
            return {}
        if not isinstance(value, dict):
            raise self.fail(path, f"expected a table, got {type_name(value)}")
        self.known_keys(value, path, allowed)
        return value

    def known_keys(self, data: dict, path: str, allowed: set[str]) -> None:
        for key in data:
            if key not in allowed:
                raise self.fail(join_key(path, key), "unknown key")

    def integer(self, data: dict, key: str, path: str, default: int | None, lo: int, hi: int) -> int:
        value = data.get(key, default)
        if value is None:
            raise self.fail(path, "missing")
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"expected an integer, got {type_name(value)}")
        if not lo <= value <= hi:
            raise self.fail(path, f"must be in {lo}..{hi}, got {value}")
        return value

    def rate(self, data: dict, key: str, path: str, default: float) -> float:
        """A stream rate in Hz within :data:`RATE_LIMITS_HZ` (epoch k is at k / rate: a
        rate of 1e-320 Hz would put epoch 1 beyond any float)."""
        value = self.number(data, key, path, default, positive=True)
        lo, hi = RATE_LIMITS_HZ
        if not lo <= value <= hi:
            raise self.fail(path, f"must be within [{lo:g}, {hi:g}] Hz, got {value:g}")
        return value

    def number(self, data: dict, key: str, path: str, default: float | None, positive: bool = False,
               limits: tuple[float, float] | None = None) -> float:
        """A finite number; ``positive``: > 0; ``limits`` (lo, hi): within [lo, hi]
        (with ``positive`` and lo = 0: within (0, hi]). See :mod:`emulator.scene.limits`."""
        value = data.get(key, default)
        if value is None:
            raise self.fail(path, "missing")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(path, f"expected a number, got {type_name(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(path, f"must be finite, got {value}")
        if positive and not value > 0:
            raise self.fail(path, f"must be > 0, got {value:g}")
        if limits is not None and value < limits[0]:
            raise self.fail(path, f"must be >= {limits[0]:.10g}, got {value:g}")
        if limits is not None and value > limits[1]:
            raise self.fail(path, f"must be <= {limits[1]:.10g}, got {value:g}")
        return value

    def boolean(self, data: dict, key: str, path: str, default: bool) -> bool:
        value = data.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(path, f"expected true or false, got {type_name(value)}")
        return value

    def vector(self, value: Any, path: str, length: int) -> list[float]:
        if not isinstance(value, list):
            raise self.fail(path, f"expected an array of {length} numbers, got {type_name(value)}")
        if len(value) != length:
            raise self.fail(path, f"expected {length} numbers, got {len(value)}")
        out = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise self.fail(f"{path}[{i}]", f"expected a number, got {type_name(v)}")
            if not math.isfinite(v):
                raise self.fail(f"{path}[{i}]", f"must be finite, got {v}")
            out.append(float(v))
        return out

    def quaternion(self, value: Any, path: str) -> list[float]:
        q = self.vector(value, path, 4)
        try:
            return normalize_quaternions(q, path).tolist()
        except PoseError as exc:
            raise self.fail(path, exc.reason) from None

    def trajectory(self, data: dict, path: str) -> Trajectory:
        has_static = "position" in data or "orientation" in data
        if "path" in data:
            if has_static:
                raise self.fail(join_key(path, "path"), "give either position/orientation or path, not both")
            return self._path(data["path"], join_key(path, "path"))
        if "position" not in data:
            raise self.fail(join_key(path, "position"), "missing")
        position = self.vector(data["position"], join_key(path, "position"), 3)
        orientation = self.quaternion(data.get("orientation", list(IDENTITY)), join_key(path, "orientation"))
        return Trajectory.static(position, orientation)

    def _path(self, value: Any, path: str) -> Trajectory:
        if not isinstance(value, list) or not value:
            raise self.fail(path, "expected a non-empty array of waypoint tables")
        times, positions, orientations = [], [], []
        for i, wp in enumerate(value):
            wp_path = f"{path}[{i}]"
            if not isinstance(wp, dict):
                raise self.fail(wp_path, f"expected a table, got {type_name(wp)}")
            self.known_keys(wp, wp_path, {"t", "position", "orientation"})
            t = self.number(wp, "t", f"{wp_path}.t", None)
            if times and not t > times[-1]:
                raise self.fail(f"{wp_path}.t", f"times must increase strictly, {t:g} follows {times[-1]:g}")
            if times and t - times[-1] < MIN_WAYPOINT_DT_S:
                raise self.fail(f"{wp_path}.t", f"must be at least {MIN_WAYPOINT_DT_S:g} s after {times[-1]:g}, got {t:g}")
            if "position" not in wp:
                raise self.fail(f"{wp_path}.position", "missing")
            times.append(t)
            positions.append(self.vector(wp["position"], f"{wp_path}.position", 3))
            if len(positions) > 1:  # the segment's speed (GPS truth reports it) must be a float
                with np.errstate(over="ignore"):
                    speed = np.abs(np.subtract(positions[-1], positions[-2])) / (times[-1] - times[-2])
                if not np.all(np.isfinite(speed)):
                    raise self.fail(f"{wp_path}.position", "too far from the waypoint before for the time between them "
                                    "(the speed is beyond the float range)")
            orientations.append(self.quaternion(wp.get("orientation", list(IDENTITY)), f"{wp_path}.orientation"))
        return Trajectory(np.array(times), np.array(positions), np.array(orientations))


def join_key(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def type_name(value: Any) -> str:
    return {
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "an array",
        dict: "a table",
    }.get(type(value), type(value).__name__)


