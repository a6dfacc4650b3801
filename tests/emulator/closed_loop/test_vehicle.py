"""The kinematic UAV (paper eq. 9), terrains, the range sensor and [receiver.vehicle]."""

import math
import os

import numpy as np
import pytest

from emulator.closed_loop.loop import ClosedLoop
from emulator.scene.reader import loads_scene
from emulator.closed_loop.vehicle import UAV, FlatTerrain, GridTerrain, RangeSensor
from firmware_proto.errors import SceneError
from scene_builders import vehicle_scene_text


# --------------------------------------------------------------------------- terrain
def plane(x, y):
    return 2.0 + 0.1 * x - 0.05 * y


def plane_grid():
    x = -10.0 + 2.0 * np.arange(11)
    y = -5.0 + 1.0 * np.arange(8)
    gx, gy = np.meshgrid(x, y)
    return GridTerrain(plane(gx, gy), -10.0, -5.0, 2.0, 1.0)


def test_flat_terrain():
    t = FlatTerrain(3.5)
    assert t.height(1e6, -2.0) == 3.5
    assert t.heights(np.zeros((2, 3)), 0.0).tolist() == [[3.5] * 3] * 2


def test_grid_is_bilinear_exact_on_planes_and_nodes():
    g = plane_grid()
    rng = np.random.default_rng(1)
    xs, ys = rng.uniform(-10, 10, 200), rng.uniform(-5, 2, 200)
    assert np.allclose([g.height(x, y) for x, y in zip(xs, ys)], plane(xs, ys), atol=1e-12)
    assert np.allclose(g.heights(xs, ys), plane(xs, ys), atol=1e-12)
    assert g.height(-10.0, -5.0) == plane(-10.0, -5.0) and g.height(10.0, 2.0) == plane(10.0, 2.0)


def test_grid_holds_the_edge_outside():
    g = plane_grid()
    assert g.height(-50.0, -5.0) == pytest.approx(plane(-10.0, -5.0))
    assert g.height(4.0, 99.0) == pytest.approx(plane(4.0, 2.0))
    assert g.heights(np.array([-50.0, 50.0]), np.array([-50.0, 50.0])).tolist() == pytest.approx(
        [plane(-10, -5), plane(10, 2)]
    )


def test_grid_bilinear_in_a_cell():
    g = GridTerrain(np.array([[0.0, 1.0], [2.0, 5.0]]), 0.0, 0.0, 1.0, 1.0)
    # (0.5, 0.5): mean of the corners for bilinear.
    assert g.height(0.5, 0.5) == 2.0
    assert g.height(0.25, 1.0) == 2.75


def test_grid_files_csv_and_npy_agree(tmp_path):
    z = np.arange(12.0).reshape(3, 4) / 7
    np.save(tmp_path / "dem.npy", z)
    (tmp_path / "dem.csv").write_text("# a comment\n" + "\n".join(",".join(repr(float(v)) for v in row) for row in z) + "\n")
    a = GridTerrain.load(tmp_path / "dem.npy", (1.0, 2.0), (0.5, 0.5))
    b = GridTerrain.load(tmp_path / "dem.csv", (1.0, 2.0), (0.5, 0.5))
    assert np.array_equal(a.z, b.z)
    assert a.height(1.7, 2.3) == b.height(1.7, 2.3)


def test_grid_rejects_bad_arrays():
    with pytest.raises(ValueError, match="at least 2 x 2"):
        GridTerrain(np.zeros((1, 5)), 0, 0, 1, 1)
    with pytest.raises(ValueError, match="non-finite"):
        GridTerrain(np.array([[0.0, np.nan], [0.0, 0.0]]), 0, 0, 1, 1)


# --------------------------------------------------------------------------- UAV
def test_uav_integrates_velocity_and_limits_it():
    uav = UAV(FlatTerrain(), (1.0, 2.0), 3.0, v_max=1.0, v_z_max=0.5)
    assert uav.position == (1.0, 2.0, 3.0)
    uav.step(0.3, 0.4, 0.2, 0.1)
    assert uav.position == pytest.approx((1.03, 2.04, 3.02))
    uav.step(3.0, 4.0, -9.0, 1.0)  # 5 m/s horizontally -> 1 m/s, vertical -> -0.5
    assert uav.position == pytest.approx((1.63, 2.84, 2.52))


def test_uav_never_goes_below_the_terrain():
    uav = UAV(FlatTerrain(10.0), (0.0, 0.0), 0.5, v_z_max=5.0)
    uav.step(0.0, 0.0, -5.0, 1.0)
    assert uav.z == 10.0 and uav.ground_contacts == 1
    g = plane_grid()
    uav = UAV(g, (0.0, 0.0), 0.0)
    uav.step(1.0, 0.0, 0.0, 1.0)  # uphill at z = S(0, 0): stops on the slope
    assert uav.z == pytest.approx(plane(1.0, 0.0))


def test_uav_orientation_is_its_yaw():
    uav = UAV(FlatTerrain(), (0.0, 0.0), 1.0, yaw_deg=90.0)
    w, x, y, z = uav.orientation
    assert (w, x, y, z) == pytest.approx((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))


def test_range_sensor_noise_is_seeded_white_and_unbiased():
    def readings(seed, n=20000):
        rng = np.random.Generator(np.random.PCG64(seed))
        s = RangeSensor(FlatTerrain(1.0), 0.05, rng)
        return np.array([s.read(0.0, 0.0, 3.0) for _ in range(n)])

    a, b = readings(4), readings(4)
    assert np.array_equal(a, b)
    assert abs(a.mean() - 2.0) < 0.002 and abs(a.std() - 0.05) < 0.002
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < 0.03
    assert RangeSensor(FlatTerrain(1.0), 0.0, None).read(5.0, 5.0, 3.0) == 2.0


# --------------------------------------------------------------------------- scenes
def vehicle_text(body: str) -> str:
    """Transmitter 1, a 2-channel receiver on a vehicle whose table is ``body``, seed 3."""
    return vehicle_scene_text(body, seed=3)


def vehicle_scene(body, source="v.toml"):
    return loads_scene(vehicle_text(body), source)


def test_vehicle_defaults_and_start_pose():
    s = vehicle_scene('start = [1.0, 2.0]\nterrain_height = 5.0\nyaw = 90.0')
    v = s.receiver.vehicle
    assert (v.kind, v.controller, v.v_max, v.r_s, v.k_c, v.k_z, v.control_rate_hz) == ("uav", "flux", 1.0, 1.0, 0.2, 1.0, 10.0)
    pos, quat = s.receiver.trajectory.at([0.0])
    assert pos.tolist() == [[1.0, 2.0, 6.0]]  # terrain 5 + r_s 1
    assert quat[0] == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])


def test_scene_without_vehicle_has_none():
    s = loads_scene(vehicle_text("").replace("[receiver.vehicle]\n", "position = [0, 0, 0]\n"), "n.toml")
    assert s.receiver.vehicle is None


@pytest.mark.parametrize(
    "body, message",
    [
        ("speed = 3", "v.toml: receiver.vehicle.speed: unknown key"),
        ('kind = "rover"', 'v.toml: receiver.vehicle.kind: must be "uav", got "rover"'),
        ('controller = "magic"', 'v.toml: receiver.vehicle.controller: must be one of external_mavlink, flux, receiver_only, got "magic"'),
        ("v_max = 0", "v.toml: receiver.vehicle.v_max: must be > 0, got 0"),
        ("range_sigma_m = -1", "v.toml: receiver.vehicle.range_sigma_m: must be >= 0, got -1"),
        ("start = [1, 2, 3]", "v.toml: receiver.vehicle.start: expected 2 numbers, got 3"),
        ('mavlink = "udpin:0.0.0.0:14550"', 'v.toml: receiver.vehicle.mavlink: only with controller = "external_mavlink"'),
        ("control_rate_hz = 2.5", "v.toml: receiver.vehicle.control_rate_hz: must be a whole multiple of rate_hz = 1, got 2.5"),
        ('terrain = "dem.csv"', "v.toml: receiver.vehicle.terrain_origin: missing: a DEM file needs terrain_origin = [x, y] (metres)"),
        ('terrain = "dem.tif"\nterrain_origin = [0, 0]\nterrain_spacing = [1, 1]', "v.toml: receiver.vehicle.terrain: a DEM file must be .npy or .csv, got 'dem.tif'"),
        ("terrain_spacing = [1, 1]", "v.toml: receiver.vehicle.terrain_spacing: only with a DEM terrain file"),
        ("search_area = [0, 0, -1, 5]", "v.toml: receiver.vehicle.search_area: expected [xmin, ymin, xmax, ymax] with xmax > xmin and ymax > ymin"),
        ("flux_reverse = 1", "v.toml: receiver.vehicle.flux_reverse: expected true or false, got an integer"),
    ],
)
def test_vehicle_errors_name_the_key(body, message):
    with pytest.raises(SceneError) as exc:
        vehicle_scene(body)
    assert str(exc.value) == message


@pytest.mark.parametrize("key, line", [("position", "position = [0, 0, 0]"), ("gps", "gps = true")])
def test_receiver_with_vehicle_rejects_its_own_pose_and_gps(key, line):
    text = vehicle_text("").replace("channels = 2\n", f"channels = 2\n{line}\n")
    with pytest.raises(SceneError, match=rf"receiver\.{key}: not allowed with receiver\.vehicle"):
        loads_scene(text, "v.toml")


def test_dem_path_is_relative_to_the_scene_file(tmp_path):
    z = np.full((3, 3), 7.0)
    np.save(tmp_path / "dem.npy", z)
    scene_file = tmp_path / "s.toml"
    scene_file.write_text(
        vehicle_text('terrain = "dem.npy"\nterrain_origin = [-1, -1]\nterrain_spacing = [1, 1]')
    )
    from emulator.scene.reader import load_scene

    s = load_scene(scene_file)
    assert s.receiver.vehicle.terrain.height(0.3, 0.3) == 7.0
    assert s.receiver.trajectory.positions[0].tolist() == [0.0, 0.0, 8.0]
    missing = tmp_path / "m.toml"
    missing.write_text(vehicle_text('terrain = "nope.csv"\nterrain_origin = [0, 0]\nterrain_spacing = [1, 1]'))
    with pytest.raises(SceneError, match=r"vehicle\.terrain: '.*nope\.csv': cannot read: No such file"):
        load_scene(missing)


@pytest.mark.parametrize("name, make, why", [
    # a FIFO named like a DEM would block the read for ever
    ("x.csv", os.mkfifo, "a named pipe, not a regular file: only regular files are read as a terrain file"),
    ("x.npy", lambda path: path.write_bytes(b""), "No data left in file"),  # (numpy's EOFError)
])
def test_a_dem_that_is_a_named_pipe_or_empty_is_one_line(tmp_path, name, make, why):
    make(tmp_path / name)
    scene_file = tmp_path / "s.toml"
    dem = f'terrain = "{name}"\nterrain_origin = [0, 0]\nterrain_spacing = [1, 1]'
    scene_file.write_text(vehicle_text(dem))
    from emulator.scene.reader import load_scene

    with pytest.raises(SceneError) as exc:
        load_scene(scene_file)
    assert str(exc.value) == f"{scene_file}: receiver.vehicle.terrain: '{tmp_path / name}': {why}"


# --------------------------------------------------------------------------- height hold
def test_height_hold_converges_to_r_s_over_a_slope(tmp_path):
    g = plane_grid()
    np.save(tmp_path / "dem.npy", g.z)
    f = tmp_path / "s.toml"
    f.write_text(
        vehicle_scene_text(
            'start = [-8.0, 0.0]\nstart_height = 4.0\nr_s = 1.5\nrange_sigma_m = 0.01\n'
            'terrain = "dem.npy"\nterrain_origin = [-10, -5]\nterrain_spacing = [2, 1]',
            tx_position=[200.0, 0.0, 0.0], seed=3,  # out of range: hover
        )
    )
    from emulator.scene.reader import load_scene

    loop = ClosedLoop(load_scene(f))
    r = loop.run(15.0)
    height = r.position[:, 2] - g.heights(r.position[:, 0], r.position[:, 1])
    assert height[0] == pytest.approx(4.0)
    assert abs(height[-1] - 1.5) < 0.01  # exp(-15 k_z) of 2.5 m, plus range noise
    assert np.all(np.diff(height[:40]) < 0)  # a clean descent, no overshoot
    assert r.ground_contacts == 0
