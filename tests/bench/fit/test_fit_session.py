"""A whole campaign through the real pipeline, no mocks: the emulator's receiver, GPS and
attitude byte streams for a 15-minute walk -> a session directory (as ``arva-bench log``
writes it) -> ``arva-bench fit SESSION --json`` (through ``export``) -> the scene's
kappa_eq and r_en, and every detected and censored epoch counted."""

import json

import numpy as np
import pytest

from bench.cli import main
from fit_campaign import Walk, walk_poses
from bench.session import SessionWriter
from emulator.frames.attitude import quaternion_to_hpr
from emulator.frames.geodesy import Origin, enu_to_geodetic
from emulator.receiver.model import ModelParams
from emulator.scene.reader import loads_scene
from emulator.pipeline import scene_streams
from firmware_proto.decoder import Decoder
from firmware_proto.events import Epoch

pytestmark = pytest.mark.slow

SECONDS = 900
ORIGIN = Origin(46.5, 8.0, 2500.0)
TX_POS = (0.0, 0.0, -1.0)
TX_Q = (0.9238795325112867, 0.0, 0.3826834323650898, 0.0)  # dipole pitched 45 deg about y


def scene_text() -> str:
    rng = np.random.default_rng(2026)
    pos, quat = walk_poses(np.arange(SECONDS, dtype=float), Walk(), rng)
    waypoints = ",\n".join(
        f"  {{ t = {k}.0, position = {p.tolist()}, orientation = {q.tolist()} }}" for k, (p, q) in enumerate(zip(pos, quat))
    )
    return f"""spec = 1
seed = 31
rate_hz = 1.0
[origin]
lat = {ORIGIN.lat}
lon = {ORIGIN.lon}
alt = {ORIGIN.alt}
[ground_truth]
start_utc = 2026-01-15T10:00:00Z
gps_rate_hz = 1.0
attitude_rate_hz = 1.0
lat_lon_decimals = 7
[effects]
noise = true
[[transmitters]]
id = 1
position = {list(TX_POS)}
orientation = {list(TX_Q)}
[receiver]
channels = 1
gps = true
attitude = true
path = [
{waypoints},
]
"""


def write_session(directory, scene) -> list[Epoch]:
    """The three streams, one read per epoch, stamped at the epoch's scene time."""
    lat, lon, alt = (float(v) for v in enu_to_geodetic(*TX_POS, ORIGIN))
    heading, roll, pitch = (float(v) for v in quaternion_to_hpr(TX_Q))
    names = {"arva": "arva", "gps": "gps-rx", "attitude": "attitude-rx"}
    manifest = {
        "devices": {name: {"kind": label, "url": "emulated", "role": "rx", "baudrate": 115200}
                    for label, name in names.items()},
        "origin": {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt},
        "tx_poses": {"1": {"lat": lat, "lon": lon, "alt": alt, "heading": heading, "roll": roll, "pitch": pitch}},
    }  # fmt: skip
    writer = SessionWriter(directory, manifest)
    epochs = []
    mono0, utc0 = 1000.0, 1768471200.0  # 2026-01-15T10:00:00Z
    for stream in scene_streams(scene):
        for k in range(SECONDS):
            data = stream.render(k, 1)
            writer.raw(names[stream.label], data, mono0 + k, utc0 + k)
            if stream.label == "arva":
                epochs += [ev for ev in Decoder().feed(data) if isinstance(ev, Epoch)]
    writer.close()
    return epochs


@pytest.mark.timeout(120)
def test_fit_of_a_logged_session_recovers_the_scene_model(tmp_path, capsys):
    scene = loads_scene(scene_text(), "walk.toml")
    epochs = write_session(tmp_path / "session", scene)
    assert len(epochs) == SECONDS
    censored = sum(1 for e in epochs if e.slots[0][0] == -1)
    assert 50 < censored < SECONDS - 300  # the walk reaches past the range limit, mostly inside it

    code = main(["fit", str(tmp_path / "session"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    fit = json.loads(out)
    truth = ModelParams()
    assert (fit["n_rows"], fit["n_censored"]) == (SECONDS, censored)
    # Ground truth went through NMEA (0.19 mm) and $PASHR (0.01 deg): the bounds hold.
    assert abs(fit["kappa_eq"] / truth.kappa_eq - 1) < 0.02, fit
    assert abs(fit["r_en"] / truth.r_en - 1) < 0.10, fit
    # ... and the reported standard errors are honest about it (4 sigma).
    assert abs(fit["kappa_eq"] - truth.kappa_eq) < 4 * fit["kappa_eq_se"], fit
    assert abs(fit["r_en"] - truth.r_en) < 4 * fit["r_en_se"], fit
