"""Ground-truth streams and where they go: speed and track of the segment travelled, GGA
within 82 characters for every accepted lat_lon_decimals, streams to files and stdout,
--link DIR created on a fresh machine."""

import datetime as dt
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import repo_paths
from scene_builders import one_tx

from bench.ground_truth.gps import GpsReader
from emulator.cli import main
from emulator.frames.trajectory import Trajectory
from emulator.pipeline import scene_streams
from emulator.scene.reader import load_scene, loads_scene
from emulator.testing.scene_toml import dumps
from emulator.truth.nmea import gga_sentence, gps_sentences

FIELD_WALK = repo_paths.SCENES / "field_walk.toml"
KNOTS = 3600 / 1852


def rmcs(stream, k0, n):
    return [f for f in GpsReader().feed(stream.render(k0, n)) if f.sentence == "RMC"]


def test_velocity_is_the_segment_being_travelled():
    tr = Trajectory(np.array([0.0, 10.0, 20.0]), np.array([[0.0, 0, 0], [10.0, 0, 0], [10.0, 20.0, 0]]),
                    np.tile([1.0, 0, 0, 0], (3, 1)))  # fmt: skip
    v = tr.velocity([-1.0, 0.0, 5.0, 10.0, 19.999, 20.0, 30.0])
    assert v.tolist() == [[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 2, 0], [0, 2, 0], [0, 0, 0], [0, 0, 0]]
    assert Trajectory.static([1.0, 2.0, 3.0]).velocity([0.0, 5.0]).tolist() == [[0, 0, 0], [0, 0, 0]]


def test_first_rmc_of_the_field_walk_says_the_walking_speed():
    scene = load_scene(FIELD_WALK)
    gps = {s.label: s for s in scene_streams(scene)}["gps"]
    first, = rmcs(gps, 0, 1)
    # First leg: (70, 0) to (0, 60) in 60 s: 1.537 m/s toward 310.6 deg (was half of it).
    v = math.hypot(70, 60) / 60
    assert first.speed_knots == pytest.approx(v * KNOTS, abs=1e-3)
    assert first.course == pytest.approx(math.degrees(math.atan2(-70, 60)) % 360, abs=0.01)
    # At the waypoint t = 60 s the walker starts the second leg: (0, 60) to (-50, 0).
    *_, at_waypoint = rmcs(gps, 1, 60)
    assert at_waypoint.speed_knots == pytest.approx(math.hypot(50, 60) / 60 * KNOTS, abs=1e-3)
    assert at_waypoint.course == pytest.approx(math.degrees(math.atan2(-50, -60)) % 360, abs=0.01)


@settings(max_examples=300, deadline=None)
@given(
    lat=st.floats(-90, 90),
    lon=st.floats(-180, 180),
    alt=st.floats(-9999.0, 999_999.0),
    decimals=st.integers(4, 7),
)
def test_gga_within_82_characters_for_every_accepted_decimals(lat, lon, alt, decimals):
    """As the emulated GPS sends them (HDOP 0.8, 12 satellites), from -10 km to 1000 km."""
    utc = dt.datetime(2026, 1, 1, 23, 59, 59, 990000, tzinfo=dt.timezone.utc)
    out = gps_sentences(utc, lat, lon, alt, velocity_enu=(-300.0, -300.0), lat_lon_decimals=decimals, short=True)
    assert all(len(line) + 2 <= 82 for line in out.split(b"\r\n")[:-1])


def test_short_fields_keep_their_value():
    utc = dt.datetime(2026, 1, 1, tzinfo=dt.timezone.utc)
    long = gga_sentence(utc, 46.5, 8.0, 2500.0, geoid_sep=48.25, hdop=1.2)
    short = gga_sentence(utc, 46.5, 8.0, 2500.0, geoid_sep=48.25, hdop=1.2, short=True)
    assert b",1.20,2451.750,M,48.250,M," in long and b",1.2,2451.750,M,48.25,M," in short


WORST = """spec = 1
[origin]
lat = -89.99
lon = -179.99
alt = -9000.0
[ground_truth]
lat_lon_decimals = {decimals}
gps_rate_hz = 10.0
[[transmitters]]
id = 1
position = [0.0, 0.0, 0.0]
[receiver]
gps = true
path = [ {{ t = 0.0, position = [0.0, 0.0, 0.0] }}, {{ t = 1.0, position = [300.0, -300.0, -500.0] }} ]
"""


@pytest.mark.parametrize("decimals", [4, 5, 6, 7])
def test_scene_gps_stream_within_82_characters(decimals):
    scene = loads_scene(WORST.format(decimals=decimals), "worst.toml")
    gps = {s.label: s for s in scene_streams(scene)}["gps"]
    lines = gps.render(0, 20).split(b"\r\n")[:-1]
    assert len(lines) == 40 and max(len(line) + 2 for line in lines) <= 82


def truth_scene() -> str:
    """one_tx() with an origin, the receiver's GPS and attitude streams (attitude at 2 Hz)."""
    scene = one_tx()
    scene["receiver"].update(gps=True, attitude=True)
    return dumps({**scene, "origin": {"lat": 46.5, "lon": 8.0}, "ground_truth": {"attitude_rate_hz": 2.0}})


TRUTH = truth_scene()


def test_streams_to_files_and_stdout(tmp_path, capsysbinary):
    scene_file = tmp_path / "truth.toml"
    scene_file.write_text(TRUTH)
    arva, gps = tmp_path / "arva.nmea", tmp_path / "out" / "gps.nmea"
    gps.parent.mkdir()
    argv = ["--scene", str(scene_file), "--stream", f"arva={arva}", "--stream", f"gps={gps}",
            "--stream", "attitude=-", "--frames", "3", "--speed", "0"]  # fmt: skip
    assert main(argv) == 0
    expected = {s.label: s.render(0, 6 if s.label == "attitude" else 3) for s in scene_streams(loads_scene(TRUTH, "t"))}
    assert arva.read_bytes() == expected["arva"] and gps.read_bytes() == expected["gps"]
    assert capsysbinary.readouterr().out == expected["attitude"]


@pytest.mark.pty
def test_link_dir_is_created(tmp_path, capsys):
    links = tmp_path / "fresh" / "links"
    assert main(["--port", "pty", "--link", str(links), "--frames", "1", "--speed", "0"]) == 0
    assert links.is_dir() and list(links.iterdir()) == []  # the links go when the emulator stops
    announced = capsys.readouterr().out.split()
    assert announced[0] == "arva" and announced[1].startswith("/dev/pts/")


def test_link_that_is_a_file_is_refused(tmp_path, capsys):
    blocker = tmp_path / "links"
    blocker.write_text("not a directory")
    with pytest.raises(SystemExit) as info:  # refused by its argparse type (cli_types.output_dir)
        main(["--port", "pty", "--link", str(blocker), "--frames", "1", "--speed", "0"])
    assert info.value.code == 2
    assert capsys.readouterr().err == f"arva-emulate: error: argument --link: {blocker}: exists and is not a directory\n"
