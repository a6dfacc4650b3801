"""arva-bench dash over real ptys: arva-emulate in a subprocess with the dashboard's reader
thread on the pty it announces (the default scene's epoch in the channel table), and the
command itself run in a pseudo-terminal, recording and quitting."""

from __future__ import annotations

import asyncio
import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
import time

import pytest
from dash_helpers import DEFAULT_SLOTS
from scene_builders import field_scene
from emulator.testing import EmulatorProcess

from bench.dash.app import DashApp, DashConfig
from bench.dash.widgets import ChannelTable, GroundTruthPanel, LinkPanel
from bench.logger import DeviceSpec
from bench.session import read_jsonl, read_manifest

pytestmark = [pytest.mark.subprocess, pytest.mark.pty]

EXPECTED_ROWS = [
    "  4    7.61  -62 mid",
    "  2    9.26    0 mid",
    "  1   19.05   21 mid",
    "  3   28.08  -72 mid",
]


@pytest.mark.timeout(60)
def test_dash_shows_the_emulator_on_a_pty(tmp_path):
    emu = EmulatorProcess("--port", "pty", "--speed", "10")
    try:
        path = emu.ports["arva"]
        config = DashConfig(specs=[DeviceSpec("arva", "arva", path, "rx")], record_dir=tmp_path, stale_after=2.0)

        async def go() -> tuple[list[str], str]:
            app = DashApp(config)
            async with app.run_test(size=(80, 24)) as pilot:
                table = app.query_one(ChannelTable)
                for _ in range(200):  # up to 20 s
                    rows = table.plain.splitlines()[1:]
                    if app.receivers["arva"].epochs >= 3 and [r[:20] for r in rows] == EXPECTED_ROWS:
                        break
                    await asyncio.sleep(0.1)
                rows = [r[:20] for r in table.plain.splitlines()[1:]]
                links = app.query_one(LinkPanel).plain.splitlines()[1]
                await pilot.press("q")
            return rows, links

        rows, links = asyncio.run(asyncio.wait_for(go(), timeout=40))
        assert rows == EXPECTED_ROWS
        assert links.split()[:2] == ["arva", "up"]
    finally:
        emu.kill()


def _drain(fd: int, seconds: float, out: bytearray) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            try:
                out += os.read(fd, 65536)
            except OSError:  # the child closed the terminal
                return


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_arva_bench_dash_in_a_terminal_records_and_quits(tmp_path):
    """The command itself on a pseudo-terminal (80x24): r, r records a session from the
    bytes the dashboard reads; q quits at once and cleanly."""
    master, slave = pty.openpty()
    fcntl.ioctl(master, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", "dash", "arvaemu://?speed=4", "--record-dir", str(tmp_path)],
        stdin=slave, stdout=slave, stderr=slave, env={**os.environ, "TERM": "xterm-256color"},
        start_new_session=True,
    )  # fmt: skip
    os.close(slave)
    out = bytearray()
    try:
        _drain(master, 2.0, out)  # started, showing epochs
        os.write(master, b"r")
        _drain(master, 1.5, out)  # about six epochs at 4 Hz
        os.write(master, b"r")
        _drain(master, 0.3, out)
        os.write(master, b"q")
        t0 = time.monotonic()
        while proc.poll() is None and time.monotonic() - t0 < 10:
            _drain(master, 0.1, out)
        quit_s = time.monotonic() - t0
        assert proc.wait(timeout=1) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    assert quit_s < 5
    (session,) = tmp_path.iterdir()
    assert b"last recording: " + str(session).encode() in bytes(out)
    manifest = read_manifest(session)
    assert manifest["devices"]["arva"]["url"] == "arvaemu://?speed=4"
    assert manifest["summary"]["stopped_by"] == "user"
    epochs = [r for r in read_jsonl(session / "arva.jsonl") if "seq" in r]
    assert len(epochs) >= 3 and all(r["slots"] == [list(s) for s in DEFAULT_SLOTS] for r in epochs)


SCENE_WITH_TRUTH = field_scene(
    {"channels": 1, "gps": True, "attitude": True, "position": [12.0, 5.0, 1.0], "orientation": [1.0, 0.0, 0.0, 0.0]},
    {"gps_rate_hz": 1.0, "attitude_rate_hz": 2.0, "lat_lon_decimals": 7}, rate_hz=1.0,
)


@pytest.mark.timeout(60)
def test_dash_ground_truth_from_emulated_gps_and_attitude_ptys(tmp_path, scene_file):
    """Receiver, GPS and $PASHR on three ptys; a surveyed transmitter: the true distance
    sqrt(12^2 + 5^2 + 2^2) = 13.15 m appears next to d, and the receiver's ENU pose."""
    from emulator.frames.geodesy import Origin, enu_to_geodetic

    scene = scene_file(SCENE_WITH_TRUTH, "truth.toml")
    tx = [float(v) for v in enu_to_geodetic(0.0, 0.0, -1.0, Origin(46.5, 8.0, 2500.0))]
    emu = EmulatorProcess("--scene", str(scene), "--port", "pty", "--speed", "10", streams=3)
    try:
        specs = [DeviceSpec("arva", "arva", emu.ports["arva"], "rx"),
                 DeviceSpec("gps-rx", "gps", emu.ports["gps"], "rx"),
                 DeviceSpec("attitude-rx", "attitude", emu.ports["attitude"], "rx")]  # fmt: skip
        config = DashConfig(specs=specs, record_dir=tmp_path, origin=[46.5, 8.0, 2500.0], tx_poses=[(1, tx)],
                            scene_truth=False)  # fmt: skip

        async def go() -> tuple[str, str]:
            app = DashApp(config)
            async with app.run_test(size=(80, 24)) as pilot:
                table, truth = app.query_one(ChannelTable), app.query_one(GroundTruthPanel)
                for _ in range(200):  # up to 20 s
                    if "13.15" in table.plain and "hdg" in truth.plain:
                        break
                    await asyncio.sleep(0.1)
                out = table.plain, truth.plain
                await pilot.press("q")
            return out

        table, truth = asyncio.run(asyncio.wait_for(go(), timeout=40))
    finally:
        emu.kill()
    row = table.splitlines()[1].split()
    assert row[0] == "1" and row[4] == "13.15"
    assert float(row[5]) == pytest.approx(float(row[1]) - 13.15, abs=0.011)
    lines = truth.splitlines()
    assert lines[1].split() == ["rx", "gps", "12.00", "5.00", "1.00"]
    assert lines[2].startswith("     fix q1")
    assert lines[3].split()[:2] == ["hdg", "90.0"]
    assert lines[4].split() == ["tx1", "surveyed", "0.00", "0.00", "-1.00"]
