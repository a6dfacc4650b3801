"""Firmware in the loop (issue 31): the example firmware (firmware_proto/examples/search_fw,
our C codec unchanged) runs on QEMU's mps2-an385, reads the emulator's stream on UART0 and
reports each decision on UART1; the tests step the emulator and compare every decision
with the Python reference device under test (docs/examples/search_dut.py) fed the very
bytes the emulator offered UART0 (its capture).

Needs qemu-system-arm, gcc-arm-none-eabi and libnewlib-arm-none-eabi (`make test` installs
them where it can: root and apt). Elsewhere these tests skip with one line naming the
packages; under CI (CI=true) a missing tool fails them instead.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
from pathlib import Path

import pytest
import repo_paths

from emulator.testing.qemu import EXAMPLE_FIRMWARE, PACKAGES, Board, build_firmware, missing_tools

ROOT = repo_paths.ROOT
RATE_HZ = 10.0

_missing = missing_tools()
if _missing:
    _why = "firmware in the loop needs " + ", ".join(_missing) + ": apt-get install " + " ".join(PACKAGES[m] for m in _missing)
    if os.environ.get("CI"):
        pytest.fail(_why, pytrace=False)
    pytestmark = pytest.mark.skip(reason=_why)


def _load_reference():
    spec = importlib.util.spec_from_file_location("search_dut", ROOT / "docs" / "examples" / "search_dut.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


DUT = _load_reference()


def reference_decisions(captured: bytes) -> list[dict]:
    """What search_dut.py reports for these bytes (its read loop, lines split at LF)."""
    search, epochs, out = DUT.Search(), DUT.Epochs(), []
    for line in captured.split(b"\n"):
        fields = DUT.parse_parva(line)
        done = epochs.feed(fields) if fields is not None else None
        if done is not None:
            seq, slots = done
            search.epoch(slots)
            out.append({"seq": seq, "state": search.state, "target": search.target, "d": search.d})
    return out


def without_bytes(decisions: list[dict]) -> list[dict]:
    return [{k: v for k, v in d.items() if k != "bytes"} for d in decisions]


@pytest.fixture(scope="module")
def firmware(tmp_path_factory) -> Path:
    return build_firmware(EXAMPLE_FIRMWARE, tmp_path_factory.mktemp("fw-build"))


def settle(loop, epochs: int) -> list[dict]:
    """Step ``epochs`` epochs, one at a time, each read back before the next."""
    for _ in range(epochs):
        k = loop.emu.step() - 1
        loop.decision(k)
    return loop.decisions()


def check_against_reference(loop) -> list[dict]:
    """Every decision equals the reference's on the captured bytes; no byte lost."""
    captured = loop.captured()
    got = loop.decisions()
    assert without_bytes(got) == reference_decisions(captured)
    assert got[-1]["bytes"] == len(captured)  # the firmware's decoder counted every byte offered
    return got


SEARCH_SCENE = {
    "spec": 1,
    "rate_hz": RATE_HZ,
    "transmitters": [{"id": 1, "position": [120.0, 0.0, 0.0]}],  # out of range
    "receiver": {"channels": 2, "position": [0.0, 0.0, 0.0]},
}


@pytest.mark.subprocess
def test_build_prints_size_and_stack(firmware):
    log = (firmware.parent / "build.log").read_text()
    size = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*search_fw.elf$", log, re.M)
    assert size is not None, log
    text, data, bss = map(int, size.groups())
    assert text < 8192 and data + bss < 2048  # a small part of a Cortex-M3's memory
    stack = re.search(r"^stack: (\d+) bytes worst case \(main \d+ -> arva_decoder_next \d+", log, re.M)
    assert stack is not None and int(stack.group(1)) < 1024, log


@pytest.mark.subprocess
@pytest.mark.pty
def test_acquires_keeps_target_and_locates(arva_firmware, firmware):
    loop = arva_firmware(firmware, scene=SEARCH_SCENE)
    boot = loop.board.wait_for(lambda lines: len(lines) >= 1)[0]
    assert json.loads(boot)["event"] == "boot"
    emu = loop.emu
    assert [d["state"] for d in settle(loop, 3)] == ["no_signal"] * 3

    # Transmitter 1 enters range at 30 m on the dipole axis: acquired, coarse.
    k = emu.set_transmitter(1, position=[30.0, 0.0, 0.0])
    settle(loop, 1)
    assert without_bytes([loop.decision(k)]) == [{"seq": k, "state": "coarse", "target": 1, "d": 2751}]

    # A second transmitter appears, much closer: the target stays transmitter 1.
    k = emu.set_transmitter(2, position=[0.0, 5.0, 0.0])
    settle(loop, 2)
    assert without_bytes([loop.decision(k + 1)]) == [{"seq": k + 1, "state": "coarse", "target": 1, "d": 2751}]

    # Transmitter 1 comes near: fine at 8 m, located at 2 m (183 cm).
    emu.set_transmitter(1, position=[8.0, 0.0, 0.0])
    assert settle(loop, 1)[-1]["state"] == "fine"
    k = emu.set_transmitter(1, position=[2.0, 0.0, 0.0])
    settle(loop, 1)
    assert without_bytes([loop.decision(k)]) == [{"seq": k, "state": "located", "target": 1, "d": 183}]
    got = check_against_reference(loop)
    assert len(got) == k + 1  # one decision per epoch, none missing


@pytest.mark.subprocess
@pytest.mark.pty
def test_survives_unplug_and_corrupted_burst(arva_firmware, firmware):
    loop = arva_firmware(firmware, scene={**SEARCH_SCENE, "transmitters": [{"id": 1, "position": [8.0, 0.0, 0.0]}]})
    emu = loop.emu
    settle(loop, 5)
    assert loop.decisions()[-1]["state"] == "fine"

    # A 2 s unplug (20 epochs at 10 Hz): the UART goes silent, the firmware keeps its target.
    k = emu.fault("disconnect", seconds=2.0)
    emu.step(int(2 * RATE_HZ))  # written into the outage: nothing reaches UART0
    k_back = emu.step() - 1
    after = loop.decision(k_back)
    assert after["state"] == "fine" and after["target"] == 1
    assert [d["seq"] for d in loop.decisions() if k <= d["seq"] < k_back] == []

    # A burst of 40 corrupted bytes: damaged epochs are dropped, the rest decided as the
    # reference decides them, and the decoder still counts every byte offered.
    emu.fault("corrupt", bytes=40)
    for _ in range(10):
        emu.step()
    k_last = emu.step() - 1
    loop.decision(k_last)
    got = check_against_reference(loop)
    assert len(got) < k_last + 1 - 2 * RATE_HZ  # the corruption cost at least one epoch
    assert got[-1]["state"] == "fine"


WALK_SCENE = {  # a receiver walking past two transmitters: no signal, coarse, fine, located
    "spec": 1,
    "rate_hz": RATE_HZ,
    "transmitters": [{"id": 1, "position": [0.0, 0.0, -1.0]}, {"id": 2, "position": [12.0, 6.0, -1.5]}],
    "receiver": {
        "channels": 2,
        "path": [
            {"t": 0.0, "position": [80.0, 0.0, 0.0]},
            {"t": 3.0, "position": [12.5, 6.0, 0.0], "orientation": [0.92388, 0.0, 0.0, 0.38268]},
            {"t": 4.0, "position": [12.5, 6.5, 0.0]},
            {"t": 6.0, "position": [-30.0, 10.0, 0.0]},
        ],
    },
}
NOISY_SCENE = {  # EMI noise on, seeded: readings scatter near the range limit
    "spec": 1,
    "seed": 11,
    "rate_hz": RATE_HZ,
    "model": {"r_en": 40.0},
    "effects": {"noise": True},
    "transmitters": [{"id": 1, "position": [30.0, 30.0, -1.0]}, {"id": 3, "position": [-20.0, 5.0, -1.0]}],
    "receiver": {"channels": 3, "path": [{"t": 0.0, "position": [-60.0, 0.0, 0.0]}, {"t": 6.0, "position": [40.0, 30.0, 0.0]}]},
}


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.parametrize("scene", [None, WALK_SCENE, NOISY_SCENE], ids=["default", "walk", "noisy"])
def test_decisions_equal_reference_on_scenes(arva_firmware, firmware, scene):
    loop = arva_firmware(firmware, scene=scene)
    settle(loop, 60)
    got = check_against_reference(loop)
    assert [d["seq"] for d in got] == list(range(60))
    if scene is WALK_SCENE:
        assert {d["state"] for d in got} == {"no_signal", "coarse", "fine", "located"}


@pytest.mark.subprocess
@pytest.mark.pty
def test_icount_gives_the_same_decisions(arva_firmware, firmware):
    loop = arva_firmware(firmware, scene=WALK_SCENE, icount=4)
    settle(loop, 60)
    got = check_against_reference(loop)
    assert len(got) == 60


def test_missing_firmware_is_one_clear_error(tmp_path):
    from emulator.testing.harness import EmulatorError

    with pytest.raises(EmulatorError, match=r"no-such\.elf: no such firmware image"):
        Board(tmp_path / "no-such.elf", tmp_path / "work")


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.pty
def test_a_long_step_loses_no_byte(arva_firmware, firmware):
    """1000 epochs in one step (55,780 bytes) into a UART QEMU drains at ~15 KB/s: the
    emulator waits for a reader that keeps reading (STEP_DRAIN_WAIT), nothing is dropped."""
    loop = arva_firmware(firmware, scene={**SEARCH_SCENE, "transmitters": [{"id": 1, "position": [20.0, 0.0, 0.0]}, {"id": 2, "position": [0.0, 25.0, 0.0]}]})
    k = loop.emu.step(1000) - 1
    assert loop.decision(k, timeout=60)["seq"] == 999
    got = check_against_reference(loop)
    assert len(got) == 1000 and len(loop.captured()) == 55780


FAILING_FIRMWARE_TEST = '''
from emulator.testing.qemu import EXAMPLE_FIRMWARE, build_firmware

def test_firmware_misbehaves(arva_firmware, tmp_path):
    loop = arva_firmware(build_firmware(EXAMPLE_FIRMWARE, tmp_path / "build"),
                         scene={"spec": 1, "transmitters": [{"id": 1, "position": [20.0, 0.0, 0.0]}],
                                "receiver": {"position": [0.0, 0.0, 0.0]}})
    loop.emu.step(2)
    loop.decision(1)
    assert False, "the firmware misbehaved"
'''


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(120)
def test_a_failing_firmware_test_keeps_its_artefacts(tmp_path):
    """Outside this repository, with only the installed plugin: the report names the
    folder, which holds the firmware's output, QEMU's log and the emulator's bytes."""
    import subprocess
    import sys

    (tmp_path / "test_fw.py").write_text(FAILING_FIRMWARE_TEST)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTEST_ADDOPTS", "PYTEST_PLUGINS")}
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(tmp_path), f"--basetemp={tmp_path / 'bt'}"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=110,
    )
    assert result.returncode == 1, result.stdout + result.stderr
    folder = Path(re.search(r"kept in:\n(\S+arva-firmware-0)", result.stdout).group(1))
    lines = (folder / "uart1.txt").read_text().splitlines()
    assert json.loads(lines[0])["event"] == "boot"
    assert [json.loads(x)["d"] for x in lines[1:]] == [1834, 1834]
    assert (folder / "qemu.log").exists() and "redirected to" in (folder / "qemu-stdout.txt").read_text()
    assert (folder / "emulator" / "streams" / "arva.bytes").read_bytes() == b"$PARVA,0,1,1,1,1834,0*6B\r\n$PARVA,1,1,1,1,1834,0*6A\r\n"
