"""Scene files (BRIEF 5): loading, paths, and one exact message per validation error."""

import math
import subprocess
import sys

import numpy as np
import pytest

from emulator.receiver.receiver import Receiver
from emulator.scene.reader import default_scene, load_scene, loads_scene
from emulator.testing.scene_toml import dumps
from firmware_proto.errors import SceneError
from scene_builders import one_tx

MINIMAL = dumps(one_tx())  # transmitter 1, the receiver at the origin, nothing else


def test_minimal_scene_defaults():
    s = loads_scene(MINIMAL, "m.toml")
    assert (s.spec, s.seed, s.rate_hz, s.receiver.channels) == (1, 0, 1.0, 1)
    assert s.model.kappa_eq == 1.542 and s.model.r_outer == 50.0 and s.model.q == (1.0, 1.0, 1.0)
    assert not s.effects.noise and not s.effects.research_sentences
    assert s.transmitters[0].trajectory.orientations.tolist() == [[1.0, 0.0, 0.0, 0.0]]


def test_default_scene_is_the_paper_case_study():
    s = default_scene()
    assert [tx.id for tx in s.transmitters] == [1, 2, 3, 4]
    assert [tx.trajectory.positions[0].tolist() for tx in s.transmitters] == [
        [20, 5, 0],
        [10, 0, 1],
        [20, -20, -1],
        [-6, 5, 0],
    ]
    assert s.receiver.channels == 4


def test_transmitters_sorted_by_id_and_orientation_normalised():
    s = loads_scene(
        """spec = 1
[[transmitters]]
id = 9
position = [1, 2, 3]
orientation = [2, 0, 0, 0]
[[transmitters]]
id = 3
position = [4, 5, 6]
[receiver]
position = [0, 0, 0]
""",
        "t.toml",
    )
    assert [tx.id for tx in s.transmitters] == [3, 9]
    assert s.transmitters[1].trajectory.orientations.tolist() == [[1.0, 0.0, 0.0, 0.0]]


PATH_SCENE = """spec = 1
rate_hz = 2.0
[[transmitters]]
id = 1
position = [0, 0, 0]
[receiver]
channels = 2
path = [
  { t = 0.0, position = [10.0, 0.0, 0.0] },
  { t = 2.0, position = [20.0, 0.0, 0.0], orientation = [0.0, 0.0, 0.0, 1.0] },
]
"""


def test_path_linear_slerp_and_held():
    s = loads_scene(PATH_SCENE, "p.toml")
    pos, quat = s.receiver.trajectory.at([0.0, 1.0, 2.0, 5.0])
    assert pos[:, 0].tolist() == [10.0, 15.0, 20.0, 20.0]
    np.testing.assert_allclose(quat[1], [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(quat[3], [0, 0, 0, 1], atol=1e-15)
    # Epoch k at t = k / rate_hz: epochs 0, 2, 4 are at 0 s, 1 s, 2 s.
    ep = Receiver(s).next_batch(5).epochs
    # On the dipole axis: r * cbrt(1.542 / 2) = 9.170, 11.462, 13.754, 16.047, 18.339 m.
    assert ep.d[:, 0].tolist() == [917, 1146, 1375, 1605, 1834]
    assert ep.ids[:, 1].tolist() == [-1] * 5


ERRORS = [
    ("spec = 1\n", "s.toml: receiver: missing table"),
    ("[receiver]\nposition = [0, 0, 0]\n", "s.toml: spec: missing (this program reads spec = 1)"),
    ("spec = 2\n", "s.toml: spec: version 2 is newer than this program supports (1)"),
    ('spec = "1"\n', "s.toml: spec: expected an integer, got a string"),
    ("spec = 1\ncolour = 3\n", "s.toml: colour: unknown key"),
    ("spec = 1\n[model]\nkappa = 1.5\n", "s.toml: model.kappa: unknown key"),
    ("spec = 1\n[model]\nkappa_eq = -1.5\n", "s.toml: model.kappa_eq: must be >= 1e-30, got -1.5"),
    ("spec = 1\n[model]\nr_en = inf\n", "s.toml: model.r_en: must be finite, got inf"),
    ("spec = 1\n[model]\nr_en = nan\n", "s.toml: model.r_en: must be finite, got nan"),
    ('spec = 1\n[model]\nmoment = "big"\n', "s.toml: model.moment: expected a number, got a string"),
    ("spec = 1\n[model]\nq = [1.0, 0.5]\n", "s.toml: model.q: expected 3 numbers, got 2"),
    ("spec = 1\n[model]\nq = [1.0, 0.0, 1.0]\n", "s.toml: model.q[1]: must be >= 1e-06, got 0"),
    ("spec = 1\nrate_hz = 0\n", "s.toml: rate_hz: must be within [0.001, 10000] Hz, got 0"),
    ("spec = 1\nrate_hz = 1e-320\n", "s.toml: rate_hz: must be within [0.001, 10000] Hz, got 9.99989e-321"),
    ("spec = 1\n[ground_truth]\ngps_rate_hz = 2e4\n[receiver]\nchannels = 1\nposition = [0.0, 0.0, 0.0]\n", "s.toml: ground_truth.gps_rate_hz: must be within [0.001, 10000] Hz, got 20000"),
    ("spec = 1\n[effects]\nnoise = 1\n", "s.toml: effects.noise: expected true or false, got an integer"),
    ("spec = 1\n[effects]\nglare = true\n", "s.toml: effects.glare: unknown key"),
    (
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [0, 0]\n",
        "s.toml: transmitters[0].position: expected 3 numbers, got 2",
    ),
    (
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [0, 0, inf]\n",
        "s.toml: transmitters[0].position[2]: must be finite, got inf",
    ),
    (
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [0, 0, 0]\norientation = [0, 0, 0, 0]\n",
        "s.toml: transmitters[0].orientation: quaternion norm 0 is below 1e-09",
    ),
    (
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [0, 0, 0]\norientation = [1e-10, 0, 0, 0]\n",
        "s.toml: transmitters[0].orientation: quaternion norm 1e-10 is below 1e-09",
    ),
    (
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [0, 0, 0]\n[[transmitters]]\nid = 1\nposition = [1, 0, 0]\n",
        "s.toml: transmitters[1].id: duplicate id 1 (also transmitters[0].id)",
    ),
    ("spec = 1\n[[transmitters]]\nposition = [0, 0, 0]\n", "s.toml: transmitters[0].id: missing"),
    ("spec = 1\n[[transmitters]]\nid = -3\nposition = [0, 0, 0]\n", "s.toml: transmitters[0].id: must be in 0..65535, got -3"),
    ("spec = 1\n[[transmitters]]\nid = 1\n", "s.toml: transmitters[0].position: missing"),
    (
        "spec = 1\n[receiver]\nchannels = 0\nposition = [0, 0, 0]\n",
        "s.toml: receiver.channels: must be in 1..99, got 0",
    ),
    (
        "spec = 1\n[receiver]\nposition = [0, 0, 0]\npath = [{ t = 0.0, position = [0, 0, 0] }]\n",
        "s.toml: receiver.path: give either position/orientation or path, not both",
    ),
    (
        "spec = 1\n[receiver]\npath = [{ t = 1.0, position = [0, 0, 0] }, { t = 1.0, position = [1, 0, 0] }]\n",
        "s.toml: receiver.path[1].t: times must increase strictly, 1 follows 1",
    ),
    (
        "spec = 1\n[receiver]\npath = [{ t = 0.0, position = [0, 0, 0], speed = 3 }]\n",
        "s.toml: receiver.path[0].speed: unknown key",
    ),
    (  # found by test_malformed_inputs' hypothesis: the GPS truth's speed overflowed to inf
        "spec = 1\n[receiver]\npath = [{ t = 0.0, position = [0, 0, 0] }, { t = 0.5, position = [1.7976931348623157e308, 0, 0] }]\n",
        "s.toml: receiver.path[1].position: too far from the waypoint before for the time between them "
        "(the speed is beyond the float range)",
    ),
    ("spec = 1\ntransmitters = 3\n", "s.toml: transmitters: expected an array of tables, got an integer"),
]


@pytest.mark.parametrize("text, message", ERRORS)
def test_validation_messages(text, message):
    with pytest.raises(SceneError) as info:
        loads_scene(text, "s.toml")
    assert str(info.value) == message


def test_toml_syntax_and_encoding_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("spec = \n")
    with pytest.raises(SceneError, match=r"^.*bad.toml: TOML syntax: Invalid value \(at line 1, column 8\)$"):
        load_scene(bad)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"spec = 1\n\xff\n")
    with pytest.raises(SceneError, match=r"bin.toml: not UTF-8 text \(byte offset 9\)$"):
        load_scene(binary)
    with pytest.raises(SceneError, match=r"nope.toml: cannot read: No such file or directory$"):
        load_scene(tmp_path / "nope.toml")


@pytest.mark.subprocess
@pytest.mark.parametrize("text, message", ERRORS[:4] + ERRORS[19:20])
def test_cli_exit_2_one_line_nothing_on_stdout(tmp_path, text, message):
    path = tmp_path / "s.toml"
    path.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--scene", str(path), "--frames", "1", "--speed", "0"],
        capture_output=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stdout == b""
    expected = message.replace("s.toml", str(path), 1) + "\n"
    assert proc.stderr.decode() == expected


@pytest.mark.parametrize("text, message", ERRORS)
def test_every_error_class_through_the_cli(tmp_path, capsys, text, message):
    """In process (fast): every class of ERRORS exits 2 with exactly its one line."""
    from emulator.cli import main

    path = tmp_path / "s.toml"
    path.write_text(text)
    assert main(["--scene", str(path), "--port", "-", "--frames", "1", "--speed", "0"]) == 2
    out, err = capsys.readouterr()
    assert (out, err) == ("", message.replace("s.toml", str(path), 1) + "\n")
