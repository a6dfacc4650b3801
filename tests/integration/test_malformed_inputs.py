"""A corpus of malformed scenes and fit CSVs with their exact one-line errors (issue 16),
and the property behind the scene limits: no accepted scene produces a reading the
encoder refuses, a division by zero or an overflow (emulator/scene/tables.py).

Malformed sessions are issue 12's corpus (bench ingest); not repeated here.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.fit.csvio import parse_csv
from bench.fit.table import COLUMNS, FitInputError
from emulator.pipeline import scene_streams
from emulator.receiver.model import ModelParams, measure, select_channels
from emulator.scene.tables import MAX_READING_M, MIN_Q, MODEL_LIMITS
from emulator.scene.reader import loads_scene
from firmware_proto.errors import SceneError
from firmware_proto.sentences import MAX_D_CM, encode_epochs

RX = "[receiver]\nchannels = 1\nposition = [0.0, 0.0, 0.0]\n"
TX = "[[transmitters]]\nid = 1\nposition = [10.0, 0.0, 0.0]\n"
VEHICLE = "[receiver]\nchannels = 1\n[receiver.vehicle]\n"
NOISE = "[effects]\nnoise = true\n"

SCENES = [
    # Model constants that used to divide by zero, overflow or exceed the protocol.
    ("spec = 1\n" + NOISE + "[model]\nr_en = 1e-300\n" + TX + RX, "s.toml: model.r_en: must be >= 1e-06, got 1e-300"),
    ("spec = 1\n" + NOISE + "[model]\nr_en = 1e300\n" + TX + RX, "s.toml: model.r_en: must be <= 1000000000, got 1e+300"),
    ("spec = 1\n[model]\nr_outer = 1e6\n" + TX + RX, "s.toml: model.r_outer: must be <= 99999.99, got 1e+06"),
    ("spec = 1\n[model]\nr_inner = 2e5\n" + TX + RX, "s.toml: model.r_inner: must be <= 99999.99, got 200000"),
    ("spec = 1\n[model]\nkappa_eq = 1e300\n" + TX + RX, "s.toml: model.kappa_eq: must be <= 1e+30, got 1e+300"),
    ("spec = 1\n[model]\nmoment = 1e-300\n" + TX + RX, "s.toml: model.moment: must be >= 1e-30, got 1e-300"),
    ("spec = 1\n[model]\nq = [1.0, 1e-300, 1.0]\n" + TX + RX, "s.toml: model.q[1]: must be >= 1e-06, got 1e-300"),
    # Closed loop: a loop without end, a position that leaves the float range.
    ("spec = 1\n" + TX + VEHICLE + "control_rate_hz = 1e308\n",
     "s.toml: receiver.vehicle.control_rate_hz: must be <= 10000, got 1e+308"),
    ("spec = 1\n" + TX + VEHICLE + "control_rate_hz = 5000\n",
     "s.toml: receiver.vehicle.control_rate_hz: at most 1000 control steps per epoch (rate_hz = 1), got 5000 Hz"),
    ("spec = 1\n" + TX + VEHICLE + "v_max = 1e308\n", "s.toml: receiver.vehicle.v_max: must be <= 100, got 1e+308"),
    ("spec = 1\n" + TX + VEHICLE + "start = [1e300, 0]\n", "s.toml: receiver.vehicle.start[0]: must be within [-1e+06, 1e+06] m, got 1e+300"),
    ("spec = 1\n" + TX + VEHICLE + "search_area = [0, 0, 1e308, 1e308]\n",
     "s.toml: receiver.vehicle.search_area[2]: must be within [-1e+06, 1e+06] m, got 1e+308"),
    # Structure: recursion, a fault that would silently stay off.
    ("spec = 1\nx = " + "[" * 5000 + "]" * 5000 + "\n", "s.toml: TOML nested too deeply"),
    ("spec = 1\n[effects]\nlink_faults = true\n[link_faults]\nloss = 0.1\nstreams = [\"toaster\"]\n" + TX + RX,
     "s.toml: link_faults.streams[0]: no stream 'toaster' in this scene (streams: arva)"),
    ("spec = 1\n" + TX + RX + "gps = true\n[origin]\nlat = 46.0\nlon = 8.0\n[effects]\nlink_faults = true\n"
     "[link_faults]\nloss = 0.1\nstreams = [\"gps:rx\"]\n",
     "s.toml: link_faults.streams[0]: no stream 'gps:rx' in this scene (streams: arva, gps)"),
    ("spec = 1\n[model]\nr_outer = 99999.99\n[effects]\nquantize = true\n[quantize]\nd_step_cm = 6000000\n" + TX + RX,
     "s.toml: quantize.d_step_cm: the largest reading (9999999 cm, from model.r_inner / r_outer) would round to 12000000 cm, "
     "beyond the protocol's 9999999"),
    ("spec = 1\n[effects]\nlink_faults = true\n[link_faults]\nstall = 0.5\nstall_ms = 1e308\n" + TX + RX,
     "s.toml: link_faults.stall_ms: must be <= 60000, got 1e+308"),
    ("spec = 1\n" + TX + RX + "gps = true\n[origin]\nlat = 46.0\nlon = 8.0\n[effects]\nground_truth_error = true\n"
     "[ground_truth_error]\ngps_sigma_m = [1.7976931348623157e308, 0, 0]\n",
     "s.toml: ground_truth_error.gps_sigma_m[0]: must be within [0, 10000], got 1.79769e+308"),
    ("spec = 1\n" + TX + "[receiver]\npath = [{ t = 0.0, position = [0, 0, 0] }, { t = 5e-324, position = [1, 0, 0] }]\n",
     "s.toml: receiver.path[1].t: must be at least 1e-06 s after 0, got 4.94066e-324"),
    (b"spec = 1\nname = \"\xff\"\n", "s.toml: not UTF-8 text (byte offset 17)"),
]


@pytest.mark.parametrize("text, message", SCENES)
def test_malformed_scene_is_one_exact_line(text, message):
    with pytest.raises(SceneError) as info:
        loads_scene(text, "s.toml")
    assert str(info.value) == message


def test_every_emitted_stream_can_carry_link_faults():
    """The reader's stream labels are the ones the emulator names its streams (both sides)."""
    text = (
        "spec = 1\n[origin]\nlat = 46.0\nlon = 8.0\n"
        "[[transmitters]]\nid = 1\nposition = [10.0, 0.0, 0.0]\ngps = true\nattitude = true\n"
        "[[transmitters]]\nid = 7\nposition = [20.0, 0.0, 0.0]\ngps = true\n"
        "[[receivers]]\nid = 2\nposition = [0.0, 0.0, 0.0]\ngps = true\n"
        "[[receivers]]\nid = 3\nposition = [1.0, 0.0, 0.0]\nattitude = true\n"
    )
    scene = loads_scene(text, "s.toml")
    labels = [s.label for s in scene_streams(scene)]
    assert labels == ["arva:2", "arva:3", "gps:rx2", "gps:tx1", "gps:tx7", "attitude:rx3", "attitude:tx1"]
    faulty = text.replace("[[transmitters]]", "[effects]\nlink_faults = true\n[link_faults]\nloss = 0.5\n"
                          f"streams = {labels!r}\n[[transmitters]]".replace("'", '"'), 1)
    assert loads_scene(faulty, "s.toml").effects.link_fault_streams == tuple(labels)


@pytest.mark.subprocess
def test_empty_scene_option_is_an_error_not_the_default_scene():
    p = subprocess.run([sys.executable, "-m", "emulator.cli", "--scene", "", "--frames", "1", "--speed", "0"],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert (p.returncode, p.stdout, p.stderr) == (2, "", "arva-emulate: error: argument --scene: expected a path, got ''\n")


def test_a_scene_or_profile_that_never_ends_or_is_too_large_is_one_line(tmp_path):
    """Issue 29, item 4: /dev/zero was read for ever (MemoryError), a FIFO blocked."""
    from emulator.files import MAX_TOML_BYTES
    from emulator.receiver.profile import load_profile_file
    from emulator.scene.reader import load_scene

    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    big.write_bytes(b"spec = 1\n" + b"#" * MAX_TOML_BYTES)
    cases = [
        ("/dev/zero", "/dev/zero: a character device, not a regular file: only regular files are read as a scene file"),
        (str(fifo), f"{fifo}: a named pipe, not a regular file: only regular files are read as a scene file"),
        (str(big), f"{big}: larger than {MAX_TOML_BYTES} bytes: not a scene file"),
    ]
    for path, message in cases:
        with pytest.raises(SceneError) as info:
            load_scene(path)
        assert str(info.value) == message
    with pytest.raises(SceneError) as info:
        load_profile_file("/dev/zero")
    assert str(info.value) == "/dev/zero: a character device, not a regular file: only regular files are read as a profile file"


# --------------------------------------------------------------------------- the limits' property
def _log_uniform(lo: float, hi: float):
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: min(hi, max(lo, 10.0**e)))


@settings(max_examples=150, deadline=None)
@given(
    st.fixed_dictionaries({k: _log_uniform(*MODEL_LIMITS[k]) for k in MODEL_LIMITS}),
    st.lists(_log_uniform(MIN_Q, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(-1e12, 1e12), min_size=6, max_size=6),
    st.integers(0, 2**32),
)
def test_any_accepted_model_gives_readings_the_protocol_carries(values, q, coords, seed):
    """Model constants anywhere within the limits, any poses, noise on and off: every
    reading encodes (d <= MAX_D_CM), nothing divides by zero or overflows."""
    params = ModelParams(q=tuple(q), **values)
    assert math.isfinite(params.w_en) and params.w_en > 0 and math.isfinite(params.noise_distance)
    rx = np.array([coords[:3]])
    tx = np.array([coords[3:], [coords[3] + params.r_outer * 0.5, coords[4], coords[5]]])
    quat = np.array([[1.0, 0.0, 0.0, 0.0]])
    # Noise points inside the unit ball (|each component| < 0.57, so the norm is < 1).
    for nz in (None, np.random.default_rng(seed).uniform(-0.57, 0.57, (1, 2, 3))):
        m = measure(rx, quat, tx, np.repeat(quat, 2, axis=0), params, noise=nz)
        assert ((m.d == -1) | ((0 <= m.d) & (m.d <= MAX_D_CM))).all()
        assert ((m.zone == 2) | (m.d <= round(max(params.r_inner, params.r_outer) * 100))).all()
        ep = select_channels(m, [1, 2], 2)
        encode_epochs(0, ep.ids, ep.d, ep.delta)


def test_largest_zone_radius_reading_encodes():
    """A transmitter right at the largest accepted r_outer gives a reading of 9,999,999 cm."""
    params = ModelParams(r_inner=1.0, r_outer=MAX_READING_M, kappa_eq=1.0, moment=1.0)
    # Broadside (receiver on y): u = (-1, 0, 0) in the receiver frame, |u_xy| = 1, dxy = r.
    m = measure([[0.0, MAX_READING_M, 0.0]], [[1.0, 0, 0, 0]], [[0.0, 0.0, 0.0]], [[1.0, 0, 0, 0]], params)
    assert int(m.d[0, 0]) == MAX_D_CM
    encode_epochs(0, np.array([[1]]), m.d, m.delta)


# --------------------------------------------------------------------------- fit CSVs
def _csv(**cells) -> str:
    row = {c: "0" for c in COLUMNS}
    row.update({"d": "500", "rx_qw": "1", "tx_qw": "1", "tx_x": "5", **cells})
    return ",".join(COLUMNS) + "\n" + ",".join(row[c] for c in COLUMNS) + "\n"


CSVS = [
    (_csv(delta="200"), "c.csv: line 2: column delta: must be within -89..89 degrees, got 200"),
    (_csv(delta="-90"), "c.csv: line 2: column delta: must be within -89..89 degrees, got -90"),
    (_csv(d="10000000"), "c.csv: line 2: column d: must be <= 9999999 cm, got 10000000"),
    (_csv(d="-2"), "c.csv: line 2: column d: must be -1 or >= 0 cm, got -2"),
    (_csv(t="nan"), "c.csv: line 2: column t: not finite: 'nan'"),
    (_csv(rx_x="1e400"), "c.csv: line 2: column rx_x: not finite: '1e400'"),
    (_csv(d="x"), "c.csv: line 2: column d: not a number: 'x'"),
    (_csv(rx_qw="0"), "c.csv: line 2: rx_qw..rx_qz: quaternion norm 0 is below 1e-09"),
    (",".join(COLUMNS) + "\n", "c.csv: no data rows"),
    ("", "c.csv: empty file (no header)"),

]


@pytest.mark.parametrize("text, message", CSVS)
def test_malformed_fit_csv_is_one_exact_line(text, message):
    with pytest.raises(FitInputError) as info:
        parse_csv(text.encode(), "c.csv")
    assert str(info.value) == "fit: " + message  # the command prints arva-bench: fit: ...


# --------------------------------------------------------------------------- scene fuzz
#: A scene with every stream kind and every effect that has numbers; one key at a time is
#: replaced by a hostile value.
BASE = """spec = 1
seed = 3
rate_hz = {rate_hz}
[origin]
lat = {lat}
lon = 8.0
[model]
kappa_eq = {kappa_eq}
moment = {moment}
r_inner = {r_inner}
r_outer = {r_outer}
r_en = {r_en}
q = [1.0, {q}, 1.0]
[effects]
noise = true
research_sentences = true
quantize = true
link_faults = true
ground_truth_error = true
[quantize]
d_step_cm = {d_step_cm}
[link_faults]
loss = {loss}
stall_ms = {stall_ms}
disconnect_every_s = {disconnect_every_s}
[ground_truth_error]
gps_sigma_m = [{gps_sigma}, 0.1, 0.1]
gps_bias_m = [{gps_bias}, 0.0, 0.0]
attitude_sigma_deg = {attitude_sigma}
[[transmitters]]
id = 1
position = [{tx_x}, 5.0, 0.0]
orientation = [{qw}, 0.0, 0.0, 1.0]
gps = true
[receiver]
channels = 2
gps = true
attitude = true
path = [{{ t = 0.0, position = [0.0, 0.0, 0.0] }}, {{ t = {t1}, position = [{rx_x}, 0.0, 0.0] }}]
"""
DEFAULTS = {
    "rate_hz": "1.0", "lat": "46.0", "kappa_eq": "1.542", "moment": "1.0", "r_inner": "3.0", "r_outer": "50.0",
    "r_en": "80.0", "q": "1.0", "d_step_cm": "1", "loss": "0.1", "stall_ms": "10.0", "gps_sigma": "0.1", "gps_bias": "0.5", "attitude_sigma": "1.0", "disconnect_every_s": "0",
    "tx_x": "20.0", "qw": "1.0", "t1": "10.0", "rx_x": "5.0",
}
VEHICLE_SCENE = """spec = 1
rate_hz = 1.0
[effects]
noise = true
[[transmitters]]
id = 1
position = [20.0, 5.0, -1.0]
[receiver]
channels = 1
[receiver.vehicle]
{key} = {value}
"""
VEHICLE_KEYS = ("v_max", "v_z_max", "r_s", "k_c", "k_z", "control_rate_hz", "range_sigma_m", "strip_width", "v_stop",
                "v_fine", "start_height", "yaw", "terrain_height")
HOSTILE = st.one_of(
    st.sampled_from(["0", "-0.0", "-1", "1e-300", "5e-324", "1e300", "1.7976931348623157e308", "-1e308", "1e-7",
                     "99999.99", "100000", "1e9", "1e30", "0.5", "2", "10000", "1e4"]),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
)


def _run_scene(scene) -> None:
    for stream in scene_streams(scene):
        stream.render(0, 3)


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(DEFAULTS)), HOSTILE, min_size=1, max_size=3))
def test_any_scene_that_validates_runs(values):
    """Whatever one to three numbers of a scene are: a one-line SceneError, or three epochs
    of every stream (receiver with noise and quantisation, $PARVH, GPS, attitude) render."""
    text = BASE.format(**{**DEFAULTS, **values})
    try:
        scene = loads_scene(text, "s.toml")
    except SceneError as exc:
        assert "\n" not in str(exc)
        return
    _run_scene(scene)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(VEHICLE_KEYS), HOSTILE)
def test_any_vehicle_scene_that_validates_runs(key, value):
    try:
        scene = loads_scene(VEHICLE_SCENE.format(key=key, value=value), "v.toml")
    except SceneError as exc:
        assert "\n" not in str(exc) and f"receiver.vehicle.{key}" in str(exc)
        return
    _run_scene(scene)


def test_the_fuzzed_scenes_validate_with_their_defaults():
    """Else the two fuzz tests above would only ever see errors."""
    scene = loads_scene(BASE.format(**DEFAULTS), "s.toml")
    labels = [s.label for s in scene_streams(scene)]
    assert labels == ["arva", "gps:rx", "gps:tx1", "attitude"]
    _run_scene(scene)
    _run_scene(loads_scene(VEHICLE_SCENE.format(key="v_max", value="2.0"), "v.toml"))
