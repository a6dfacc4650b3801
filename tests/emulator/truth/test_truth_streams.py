"""Emulated ground-truth streams: what a real GPS / attitude reader gets back."""

import datetime as dt
import math

import numpy as np
import pytest
import repo_paths

from bench.ground_truth import AttitudeReader, GpsReader
from emulator.frames.attitude import quaternion_to_hpr
from emulator.frames.geodesy import geodetic_to_enu
from emulator.scene.reader import load_scene, loads_scene
from emulator.pipeline import scene_streams
from firmware_proto.errors import SceneError

FIELD_WALK = repo_paths.SCENES / "field_walk.toml"

TWO_GPS = """spec = 1
[origin]
lat = -33.9
lon = 151.2
[ground_truth]
start_utc = "2026-06-30T23:59:58Z"
gps_rate_hz = 2.0
talker = "GN"
{effects}
[[transmitters]]
id = 3
position = [5.0, 5.0, -1.0]
gps = true
[receiver]
gps = true
attitude = true
position = [10.0, -20.0, 2.0]
orientation = [0.9238795325112867, 0.0, 0.0, 0.3826834323650898]
"""


def streams(scene):
    return {s.label: s for s in scene_streams(scene)}


def test_gps_positions_and_times_round_trip_to_the_millimetre():
    scene = load_scene(FIELD_WALK)
    gps = streams(scene)["gps"]
    fixes = [f for f in GpsReader().feed(gps.render(0, 400)) if f.sentence == "GGA"]
    assert len(fixes) == 400
    t = np.arange(400.0)
    truth, _ = scene.receiver.trajectory.at(t)
    e, n, u = geodetic_to_enu([f.lat for f in fixes], [f.lon for f in fixes], [f.alt_hae for f in fixes], scene.origin)
    np.testing.assert_allclose(np.c_[e, n, u], truth, atol=1e-3, rtol=0)
    start = dt.datetime(2026, 1, 15, 10, 0, tzinfo=dt.timezone.utc)
    assert [f.utc for f in fixes[:3]] == [start + dt.timedelta(seconds=k) for k in range(3)]
    assert all(f.valid for f in fixes)


def test_gps_speed_and_course_from_the_path():
    scene = load_scene(FIELD_WALK)
    rmc = [f for f in GpsReader().feed(streams(scene)["gps"].render(10, 1)) if f.sentence == "RMC"][0]
    # First leg: (70, 0) to (0, 60) in 60 s: 1.537 m/s toward 310.6 deg.
    v = math.hypot(70, 60) / 60
    assert rmc.speed_knots == pytest.approx(v * 3600 / 1852, abs=1e-3)
    assert rmc.course == pytest.approx((math.degrees(math.atan2(-70, 60))) % 360, abs=0.01)


def test_attitude_matches_the_path():
    scene = load_scene(FIELD_WALK)
    att = streams(scene)["attitude"]
    assert att.rate_hz == 5.0
    records = AttitudeReader().feed(att.render(0, 50))
    _, quat = scene.receiver.trajectory.at(np.arange(50) / 5.0)
    heading, roll, pitch = quaternion_to_hpr(quat)
    assert [r.heading for r in records] == pytest.approx(np.round(heading, 2).tolist(), abs=0.0051)
    assert records[0].heading == 0.0  # body x north at t = 0 (yaw +90 deg from east)
    assert all(r.roll == 0.0 and r.pitch == 0.0 for r in records)


def test_labels_with_several_gps_devices_and_rates():
    s = streams(loads_scene(TWO_GPS.format(effects=""), "two.toml"))
    assert list(s) == ["arva", "gps:rx", "gps:tx3", "attitude"]
    fixes = GpsReader().feed(s["gps:tx3"].render(0, 6))
    # 2 Hz from 23:59:58: the fifth fix is on the next day, dated from its RMC.
    ggas = [f for f in fixes if f.sentence == "GGA"]
    assert [f.utc.isoformat() for f in ggas] == [
        "2026-06-30T23:59:58+00:00",
        "2026-06-30T23:59:58.500000+00:00",
        "2026-06-30T23:59:59+00:00",
        "2026-06-30T23:59:59.500000+00:00",
        "2026-07-01T00:00:00+00:00",
        "2026-07-01T00:00:00.500000+00:00",
    ]
    assert {f.talker for f in fixes} == {"GN"}
    origin = loads_scene(TWO_GPS.format(effects=""), "two.toml").origin
    e, n, u = geodetic_to_enu(ggas[0].lat, ggas[0].lon, ggas[0].alt_hae, origin)
    # Default 5 decimals of arc-minutes: 1.9 cm north, 1.5 cm east at 34 S; height in mm.
    assert (float(e), float(n), float(u)) == pytest.approx((5.0, 5.0, -1.0), abs=0.01)
    assert float(u) == pytest.approx(-1.0, abs=0.0005)
    lines = s["gps:rx"].render(0, 50).split(b"\r\n")[:-1]
    assert max(len(line) + 2 for line in lines) <= 82  # NMEA 0183's limit, CR LF included


@pytest.mark.slow
def test_ground_truth_error_bias_dropout_and_seed():
    fx = "[effects]\nground_truth_error = true\n[ground_truth_error]\ngps_bias_m = [1.0, -2.0, 0.5]\ngps_dropout = 0.25\n"
    scene = loads_scene(TWO_GPS.format(effects=fx), "e.toml")
    out = streams(scene)["gps:rx"].render(0, 4000)
    assert out == streams(loads_scene(TWO_GPS.format(effects=fx), "e.toml"))["gps:rx"].render(0, 4000)
    ggas = [f for f in GpsReader().feed(out) if f.sentence == "GGA"]
    valid = [f for f in ggas if f.valid]
    dropped = len(ggas) - len(valid)
    assert abs(dropped - 1000) < 5 * math.sqrt(4000 * 0.25 * 0.75)
    assert all(f.quality == 0 and f.lat is None for f in ggas if not f.valid)
    e, n, u = geodetic_to_enu(valid[0].lat, valid[0].lon, valid[0].alt_hae, scene.origin)
    assert (float(e), float(n), float(u)) == pytest.approx((11.0, -22.0, 2.5), abs=0.01)


@pytest.mark.parametrize(
    "text, message",
    [
        (
            "spec = 1\n[receiver]\ngps = true\nposition = [0, 0, 0]\n",
            "g.toml: origin: missing table: receiver 1 has gps = true, which needs a geodetic origin",
        ),
        ("spec = 1\n[origin]\nlat = 91.0\nlon = 0.0\n[receiver]\nposition = [0, 0, 0]\n", None),
        (
            'spec = 1\n[ground_truth]\nstart_utc = "2026-01-01T00:00:00"\n[receiver]\nposition = [0, 0, 0]\n',
            "g.toml: ground_truth.start_utc: needs a time zone (e.g. 2026-01-15T10:00:00Z)",
        ),
        (
            'spec = 1\n[ground_truth]\ntalker = "gp"\n[receiver]\nposition = [0, 0, 0]\n',
            "g.toml: ground_truth.talker: expected two upper-case letters (GP, GN, ...), got 'gp'",
        ),
        (
            "spec = 1\n[effects]\nground_truth_error = true\n[receiver]\nposition = [0, 0, 0]\n",
            "g.toml: effects.ground_truth_error: no device has gps or attitude streams to apply it to",
        ),
    ],
)
def test_ground_truth_scene_errors(text, message):
    with pytest.raises(SceneError) as info:
        loads_scene(text, "g.toml")
    if message is None:
        assert str(info.value).startswith("g.toml: origin.lat: latitude 91.0 is outside [-90, 90] degrees")
    else:
        assert str(info.value) == message
