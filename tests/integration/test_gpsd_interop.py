"""Interop: gpsd, fed our emulated GPS pty, reports the scene's positions.

Runs when gpsd is installed (Debian/Ubuntu: ``apt-get install gpsd``); skipped otherwise.
"""

import json
import shutil
import socket
import subprocess
import time

import pytest
from scene_builders import FIELD_START_UTC, field_scene

from emulator.frames.geodesy import Origin, enu_to_geodetic
from emulator.testing import EmulatorProcess

GPSD = shutil.which("gpsd") or (shutil.which("gpsd", path="/usr/sbin:/sbin"))
pytestmark = pytest.mark.skipif(GPSD is None, reason="gpsd not installed (apt-get install gpsd)")

SCENE = field_scene(
    {"gps": True, "path": [{"t": 0.0, "position": [10.0, 20.0, 1.0]}, {"t": 100.0, "position": [110.0, 20.0, 1.0]}]},
    {"start_utc": FIELD_START_UTC, "gps_rate_hz": 5.0},
)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.timeout(60)
def test_gpsd_reports_the_emulated_positions(tmp_path, scene_file):
    scene = scene_file(SCENE, "gps.toml")
    emu = EmulatorProcess("--scene", str(scene), "--port", "pty", "--speed", "1", "--frames", "20", streams=2)
    port = free_port()
    gpsd = subprocess.Popen(
        [GPSD, "-N", "-n", "-S", str(port), "-F", str(tmp_path / "gpsd.sock"), emu.ports["gps"]],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    tpv = []
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                conn = socket.create_connection(("127.0.0.1", port), timeout=2)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        with conn:
            conn.sendall(b'?WATCH={"enable":true,"json":true};\n')
            buf = b""
            while len(tpv) < 5 and time.monotonic() < deadline:
                try:
                    chunk = conn.recv(65536)
                except socket.timeout:
                    continue
                if not chunk:
                    break
                buf += chunk
                *lines, buf = buf.split(b"\n")
                for line in lines:
                    obj = json.loads(line)
                    if obj.get("class") == "TPV" and obj.get("mode", 0) == 3:
                        tpv.append(obj)
    finally:
        gpsd.terminate()
        gpsd.wait(timeout=10)
        emu.kill()
    assert len(tpv) >= 5
    origin = Origin(46.5, 8.0, 2500.0)
    for obj in tpv:
        t = time.mktime(time.strptime(obj["time"][:19], "%Y-%m-%dT%H:%M:%S")) - time.mktime(
            time.strptime("2026-01-15T10:00:00", "%Y-%m-%dT%H:%M:%S")
        ) + float("0" + obj["time"][19:-1])
        lat, lon, alt = enu_to_geodetic(10.0 + t, 20.0, 1.0, origin)
        # gpsd prints 9 decimals; our sentences carry 5 decimals of arc-minutes (1e-7 deg).
        assert obj["lat"] == pytest.approx(float(lat), abs=2e-7)
        assert obj["lon"] == pytest.approx(float(lon), abs=2e-7)
        assert obj["altHAE"] == pytest.approx(float(alt), abs=0.001)
        assert obj["speed"] == pytest.approx(1.0, abs=0.001) and obj["track"] == pytest.approx(90.0, abs=0.01)
