"""arva-bench dash over a real pty: arva-emulate in a subprocess, the dashboard's reader
thread on the pty it announces, the default scene's epoch in the channel table."""

from __future__ import annotations

import asyncio

import pytest

from bench.dash.app import DashApp, DashConfig
from bench.dash.widgets import ChannelTable, LinkPanel
from bench.logger import DeviceSpec
from emulator_proc import EmulatorProcess

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
