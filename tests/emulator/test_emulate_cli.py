"""arva-emulate on stdout: exact bytes, nothing else on stdout, seeded replay."""

import subprocess
import sys

import pytest
from scene_builders import one_tx

import emulator.cli as emulate_cli
from emulator.cli import parse_args

NOISY = """spec = 1
seed = {seed}
[model]
r_en = 30.0
[effects]
noise = true
research_sentences = {research}
[[transmitters]]
id = 1
position = [20.0, 5.0, 0.0]
[[transmitters]]
id = 2
position = [-45.0, 5.0, 0.0]
[receiver]
channels = 2
path = [ {{ t = 0.0, position = [0.0, 0.0, 0.0] }}, {{ t = 30.0, position = [15.0, 40.0, 0.0] }} ]
"""


def emulate(*args, timeout=60):
    return subprocess.run(
        [sys.executable, "-m", "emulator.cli", *args], capture_output=True, timeout=timeout
    )


@pytest.mark.subprocess
def test_exact_bytes_one_channel(scene_file):
    proc = emulate("--scene", scene_file(one_tx(channels=1)), "--port", "-", "--frames", "3", "--speed", "0")
    assert proc.returncode == 0
    assert proc.stdout == (
        b"$PARVA,0,1,1,1,1905,21*5B\r\n"
        b"$PARVA,1,1,1,1,1905,21*5A\r\n"
        b"$PARVA,2,1,1,1,1905,21*59\r\n"
    )
    assert proc.stderr == b"arva-emulate: 3 epochs sent (arva 3), 0 bytes dropped, 0 faults injected\n"


@pytest.mark.subprocess
def test_exact_bytes_empty_slot(scene_file):
    proc = emulate("--scene", scene_file(one_tx(channels=2)), "--frames", "1", "--speed", "0")
    assert proc.stdout == b"$PARVA,0,2,1,1,1905,21*58\r\n$PARVA,0,2,2,-1,-1,-1*78\r\n"


@pytest.mark.subprocess
def test_default_scene_first_epoch():
    proc = emulate("--port", "-", "--frames", "1", "--speed", "0")
    assert proc.returncode == 0
    assert proc.stdout == (
        b"$PARVA,0,4,1,4,761,-62*4C\r\n"
        b"$PARVA,0,4,2,2,926,0*5D\r\n"
        b"$PARVA,0,4,3,1,1905,21*5C\r\n"
        b"$PARVA,0,4,4,3,2808,-72*7D\r\n"
    )


@pytest.mark.subprocess
def test_seq_wraps_at_65536(scene_file):
    proc = emulate("--scene", scene_file(one_tx(channels=1)), "--frames", "65537", "--speed", "0")
    lines = proc.stdout.split(b"\r\n")
    assert len(lines) == 65538 and lines[-1] == b""
    assert lines[65535].startswith(b"$PARVA,65535,") and lines[65536] == b"$PARVA,0,1,1,1,1905,21*5B"


@pytest.mark.subprocess
def test_seeded_noise_replays_identically_and_seed_matters(scene_file):
    a = scene_file(NOISY.format(seed=7, research="false"), "a.toml")
    b = scene_file(NOISY.format(seed=8, research="false"), "b.toml")
    run = lambda s: emulate("--scene", s, "--frames", "40", "--speed", "0").stdout  # noqa: E731
    first, again, other = run(a), run(a), run(b)
    assert first == again
    assert first != other
    assert len(first.split(b"\r\n")) == 81


@pytest.mark.subprocess
def test_research_sentences_follow_their_slot(scene_file):
    s = scene_file(NOISY.format(seed=7, research="true"))
    lines = emulate("--scene", s, "--frames", "40", "--speed", "0").stdout.decode().split("\r\n")[:-1]
    for i, line in enumerate(lines):
        if line.startswith("$PARVH"):
            prev = lines[i - 1].split(",")
            here = line.split(",")
            assert prev[0] == "$PARVA" and prev[1] == here[1] and prev[3] == here[2] and prev[4] == here[3]
    assert sum(line.startswith("$PARVH") for line in lines) >= 40


@pytest.mark.subprocess
def test_chunking_does_not_change_noisy_output(scene_file):
    s = scene_file(NOISY.format(seed=3, research="true"))
    outputs = []
    for batch in (4096, 7, 1):
        proc = subprocess.run(
            [
                sys.executable,
                "-c",
                f"import emulator.output.scheduler as s; s.FAST_BATCH={batch}; "
                f"import emulator.cli as c; c.main(['--scene', {s!r}, '--frames', '50', '--speed', '0'])",
            ],
            capture_output=True,
            timeout=60,
        )
        outputs.append(proc.stdout)
    assert outputs[0] == outputs[1] == outputs[2] and outputs[0]


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--frames", "-1"], "argument --frames: must be >= 0, got -1"),
        (["--frames", "x"], "argument --frames: expected a whole number, got 'x'"),
        (["--speed", "-2"], "argument --speed: must be 0 (as fast as possible) or within 1e-06..1e+06, got -2"),
        (["--speed", "nan"], "argument --speed: must be 0 (as fast as possible) or within 1e-06..1e+06, got nan"),
    ],
)
def test_bad_arguments_exit_2(argv, fragment, capsys):
    with pytest.raises(SystemExit) as info:
        parse_args(argv)
    assert info.value.code == 2
    assert fragment in capsys.readouterr().err


@pytest.mark.subprocess
def test_real_time_pacing_is_roughly_real_time(scene_file):
    # 3 epochs at 20 Hz scene rate and speed 1: epochs at 0, 50, 100 ms. Loose bound;
    # precise jitter is measured by the benchmark, not asserted here.
    scene = one_tx(rate_hz=20.0, channels=1)
    import time

    t0 = time.monotonic()
    proc = emulate("--scene", scene_file(scene), "--frames", "3", "--speed", "1")
    assert proc.returncode == 0 and proc.stdout.count(b"\r\n") == 3
    assert time.monotonic() - t0 >= 0.1


def test_a_failure_after_the_control_channel_started_still_closes_it(monkeypatch, tmp_path, capsys):
    """The control socket is removed even when what follows its start raises (here the
    keeper of --realtime-workers): it was left on disk before."""

    def keeper_fails(*_args, **_kwargs):
        raise OSError(24, "Too many open files")

    monkeypatch.setattr(emulate_cli, "raise_workers", keeper_fails)
    path = tmp_path / "ctl.sock"
    argv = ["--control", f"unix:{path}", "--realtime", "--realtime-workers", "--frames", "2", "--port", "-"]
    assert emulate_cli.main(argv) == 2
    assert capsys.readouterr().err == f"control unix:{path}\narva-emulate: Too many open files\n"
    assert not path.exists()
