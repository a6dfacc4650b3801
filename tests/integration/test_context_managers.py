"""Ports, pipelines, sessions, the control client and the emulator process are context
managers: leaving the block closes them (issue 30, doors)."""

import json

import pytest

from bench.session import SessionWriter
from emulator.output.ports import BufferPort
from emulator.pipeline import Pipeline
from emulator.scene.reader import default_scene
from emulator.testing import ControlClient, EmulatorProcess
from emulator.testing.scene_toml import dumps


def test_session_writer_finishes_its_manifest(tmp_path):
    with SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"}}}) as w:
        w.raw("arva", b"$PARVA\r\n", mono=1.0, utc=0.0)
    assert w.closed
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert "stop_utc" in manifest  # written by close()


def test_pipeline_closes_its_ports():
    buffer = bytearray()
    with Pipeline(default_scene(), ["arva"]) as pipe:
        (route,) = pipe.bind({"arva": BufferPort("arva", buffer)}, 0)
        pipe.step(1)
    assert buffer.startswith(b"$PARVA,0,")


@pytest.mark.subprocess
@pytest.mark.pty
def test_emulator_process_and_control_client(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(dumps({"spec": 1, "transmitters": [{"id": 1, "position": [20.0, 0.0, 0.0]}],
                            "receiver": {"position": [0.0, 0.0, 0.0]}}))
    with EmulatorProcess("--scene", str(scene), "--port", "pty", "--clock", "step",
                         "--control", f"unix:{tmp_path}/c.sock") as emu:
        with ControlClient(emu.control, timeout=5) as client:
            assert client.request("step", n=2) == {"ok": True, "epoch": 2}
        assert client._sock.fileno() == -1  # closed
    assert emu.proc.poll() is not None
