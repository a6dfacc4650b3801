"""The pytest plugin as a firmware team meets it: a test file in a folder outside this
repository, run by pytest in a subprocess with only the installed package (the plugin
comes from the ``pytest11`` entry point, nothing from our conftest or sys.path)."""

import importlib.util
import json
import os
import re
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from foreign_repo import foreign_repository
import repo_paths

from emulator.testing.scene_toml import dumps

FAILING = '''
def test_fails_after_two_epochs(arva_emulator):
    emu = arva_emulator(scene={"spec": 1, "seed": 5, "transmitters": [{"id": 1, "position": [20.0, 5.0, 0.0]}],
                               "receiver": {"position": [0.0, 0.0, 0.0]}})
    emu.step(2)
    assert False, "the device under test misbehaved"
'''


def run_pytest(folder: Path, *args: str, command: list[str] | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTEST_ADDOPTS", "PYTEST_PLUGINS")}
    return subprocess.run(
        [*(command or [sys.executable, "-m", "pytest"]), "-q", "-p", "no:cacheprovider", "--rootdir", str(folder), *args],
        cwd=folder, env=env, capture_output=True, text=True, timeout=170,
    )


def outside_scene() -> dict:
    """The SCENE dict of tests/outside/step_session.py."""
    spec = importlib.util.spec_from_file_location("outside_step_session", repo_paths.OUTSIDE / "step_session.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SCENE


def readme_example() -> str:
    """The README's pytest example, verbatim."""
    text = (repo_paths.ROOT / "README.md").read_text()
    section = text[text.index("## Testing your code against the emulator"):]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(180)
def test_step_session_outside_the_repository(tmp_path):
    (tmp_path / "test_step_session.py").write_text((repo_paths.OUTSIDE / "step_session.py").read_text())
    (tmp_path / "test_readme.py").write_text(readme_example())
    junit = tmp_path / "junit.xml"
    result = run_pytest(tmp_path, f"--junitxml={junit}", f"--basetemp={tmp_path / 'bt'}")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 passed" in result.stdout
    (case,) = [c for c in ET.parse(junit).iter("testcase") if c.get("name") == "test_step_session"]
    props = {p.get("name"): p.get("value") for p in case.iter("property")}
    assert props["arva_seed"] == "11"
    # The scene was a dict: its file was temporary, so the report carries its text.
    assert props["arva_scene"] == "<dict>"
    assert tomllib.loads(props["arva_scene_toml"]) == outside_scene()
    assert props["arva_scene_toml"] == dumps(outside_scene())
    # A passing test leaves no artefacts behind.
    assert not list((tmp_path / "bt").rglob("control-transcript.txt"))


@pytest.mark.subprocess
@pytest.mark.timeout(120)
def test_a_failing_test_keeps_the_streams_and_the_transcript(tmp_path):
    (tmp_path / "test_fails.py").write_text(FAILING)
    result = run_pytest(tmp_path, f"--basetemp={tmp_path / 'bt'}")
    assert result.returncode == 1
    out = result.stdout
    assert "arva emulator artefacts" in out, out
    folder = Path(re.search(r"kept in:\n(\S+)", out).group(1))
    assert folder.is_dir() and folder.parent.parent == tmp_path / "bt"
    assert (folder / "streams" / "arva.bytes").read_bytes() == b"$PARVA,0,1,1,1,1905,21*5B\r\n$PARVA,1,1,1,1,1905,21*5A\r\n"
    transcript = (folder / "control-transcript.txt").read_text().splitlines()
    ops = [line.split(" ", 2)[1:] for line in transcript]
    assert ops[:4] == [[">", '{"op": "status"}'], ["<", ops[1][1]], [">", '{"op": "step", "n": 2}'], ["<", '{"ok": true, "epoch": 2}']]
    assert ops[-2] == [">", '{"op": "quit"}']  # teardown stopped it
    # The pty's symlink went with the pty; which pty it was, the first status reply says.
    assert sorted(p.name for p in folder.iterdir()) == ["control-transcript.txt", "scene-0.toml", "streams"]
    assert json.loads(ops[1][1])["streams"]["arva"].startswith("/dev/pts/")


ON_A_BENCH = '''
import os

def test_on_the_bench(arva_emulator):
    emu = arva_emulator(scene={"spec": 1, "transmitters": [{"id": 1, "position": [20.0, 5.0, 0.0]}],
                               "receiver": {"position": [0.0, 0.0, 0.0]}})
    assert emu.port == os.environ["DEVICE"]
    assert emu.step(2) == 2
    emu.fault("disconnect", seconds=1.0)  # a serial device cannot vanish: the bytes are dropped
    assert emu.step(2) == 4
'''


@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.timeout(120)
def test_arva_port_sends_the_first_receiver_to_a_device(tmp_path, monkeypatch):
    """--arva-port DEVICE: the stream goes to the device (here one end of a pty pair
    standing in for a USB-serial adapter), read at the other end."""
    import select
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    device = os.ttyname(slave)
    (tmp_path / "test_bench.py").write_text(ON_A_BENCH)
    monkeypatch.setenv("DEVICE", device)
    result = run_pytest(tmp_path, f"--arva-port={device}", f"--basetemp={tmp_path / 'bt'}")
    got = bytearray()
    while select.select([master], [], [], 0.5)[0]:
        got += os.read(master, 4096)
    os.close(master)
    os.close(slave)
    assert result.returncode == 0, result.stdout + result.stderr
    # Epochs 0 and 1, then 2 and 3 lost to the outage [2 s, 3 s) ... epoch 3 at t = 3 s is back.
    assert bytes(got) == (b"$PARVA,0,1,1,1,1905,21*5B\r\n$PARVA,1,1,1,1,1905,21*5A\r\n"
                          b"$PARVA,3,1,1,1,1905,21*58\r\n")


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(180)
def test_the_fixture_passes_in_a_repository_with_its_own_emulator_and_bench_packages(tmp_path):
    """Issue 29: the harness started ``python -m emulator.cli`` in the test's working
    directory, so the user's ``emulator/`` hid ours and every test failed."""
    foreign_repository(tmp_path)
    (tmp_path / "test_step_session.py").write_text((repo_paths.OUTSIDE / "step_session.py").read_text())
    # Run as a user runs it there: the ``pytest`` command (``python -m pytest`` would put
    # the folder first on the test process's own sys.path, ahead of the plugin).
    result = run_pytest(tmp_path, f"--basetemp={tmp_path / 'bt'}", command=[str(Path(sys.executable).with_name("pytest"))])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout


def test_the_recorded_scene_text_is_the_file_read_up_to_a_cap(tmp_path):
    from importlib import resources

    from emulator.testing.plugin import MAX_RECORDED_SCENE, recorded_scene_text

    scene = tmp_path / "lab.toml"
    scene.write_text("spec = 1\n# é\n", encoding="utf-8")
    assert recorded_scene_text(str(scene)) == "spec = 1\n# é\n"
    default = (resources.files("emulator") / "scenes" / "default.toml").read_text(encoding="utf-8")
    assert recorded_scene_text(None) == default
    scene.write_text("#" * MAX_RECORDED_SCENE + "\n")
    assert recorded_scene_text(str(scene)) == f"<{MAX_RECORDED_SCENE + 1} bytes: longer than {MAX_RECORDED_SCENE}, not recorded>"
    assert recorded_scene_text(str(tmp_path / "gone.toml")).startswith("<not readable: [Errno 2] No such file or directory")
