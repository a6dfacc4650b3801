"""arva-bench dash at 80x24, as SVG snapshots (pytest-textual-snapshot). Deterministic:
the data are injected messages, the clock is fixed, no wall-clock text is shown.
Update after an intended change with ``pytest tests/bench/dash/test_dash_snapshots.py --snapshot-update``
and look at the SVGs in tests/bench/dash/__snapshots__/."""

from __future__ import annotations

import asyncio

import pytest
from dash_helpers import T0, FakeClock, inject, make_app, save_walk_screenshot, walk_app, walk_messages
import repo_paths

from bench.dash.messages import AttitudeReceived, EpochReceived, FixReceived, LinkCounters, LinkStatus
from bench.logger import DeviceSpec

pytestmark = pytest.mark.timeout(60)


def test_walk_past_the_default_scene(snap_compare, tmp_path):
    """Scene truth, the nearest channel switching from 4 to 2, d histories."""

    async def before(pilot):
        await inject(pilot, walk_messages())

    assert snap_compare(walk_app(tmp_path), terminal_size=(80, 24), run_before=before)


def test_field_kit_with_a_stale_gps_and_an_unplugged_attitude_unit(snap_compare, tmp_path):
    specs = [DeviceSpec("arva", "arva", "/dev/ttyUSB0", "rx"), DeviceSpec("gps-rx", "gps", "/dev/ttyACM0", "rx"),
             DeviceSpec("attitude-rx", "attitude", "/dev/ttyUSB1", "rx")]  # fmt: skip
    app = make_app(tmp_path, specs=specs, clock=FakeClock(T0 + 5.3), origin=[46.5, 8.0, 2500.0],
                   tx_poses=[(1, [46.50009, 8.00013, 2498.5])])  # fmt: skip
    fix = {"sentence": "GGA", "talker": "GP", "time": "08:00:04", "lat": 46.50002, "lon": 8.00001, "alt_hae": 2500.4,
           "alt_msl": 2450.4, "quality": 2, "sats": 11, "hdop": 0.7, "status": None, "mode": None,
           "speed_knots": None, "course": None, "valid": True}  # fmt: skip

    async def before(pilot):
        await inject(pilot, [
            FixReceived("gps-rx", "rx", fix, T0 + 1),
            AttitudeReceived("attitude-rx", "rx", 41.5, 2.0, -4.5, [0.9355, -0.0027, -0.0399, 0.3514], T0 + 2),
            *[EpochReceived("arva", "rx", 100 + k, [(1, 1210 - 35 * k, 21 + k), (-1, -1, -1)], T0 + k) for k in range(5)],
            EpochReceived("arva", "rx", 106, [(1, 1031, 27), None], T0 + 5.2, complete=False, gap=1),
            LinkStatus("arva", "arva", "rx", "/dev/ttyUSB0", "up",
                       LinkCounters(reads=41, bytes=2024, records=6, checksum_errors=1, errors=2, seq_gaps=1,
                                    dropped_bytes=31, last_data_mono=T0 + 5.2)),
            LinkStatus("gps-rx", "gps", "rx", "/dev/ttyACM0", "up",
                       LinkCounters(reads=12, bytes=1488, records=4, last_data_mono=T0 + 1)),
            LinkStatus("attitude-rx", "attitude", "rx", "/dev/ttyUSB1", "down",
                       LinkCounters(reads=30, bytes=2160, records=30, reconnects=1, last_data_mono=T0 + 2),
                       "[Errno 2] could not open port /dev/ttyUSB1"),
        ])  # fmt: skip

    assert snap_compare(app, terminal_size=(80, 24), run_before=before)


def test_help_screen(snap_compare, tmp_path):
    async def before(pilot):
        await inject(pilot, walk_messages())

    assert snap_compare(walk_app(tmp_path), press=["question_mark"], terminal_size=(80, 24), run_before=before)


def test_docs_screenshot_is_current(tmp_path):
    """docs/dash.svg is what the app draws now (regenerate: python tests/dash_helpers.py docs/dash.svg)."""
    out = tmp_path / "dash.svg"
    asyncio.run(asyncio.wait_for(save_walk_screenshot(str(out), tmp_path), timeout=30))
    docs = repo_paths.ROOT / "docs" / "dash.svg"
    assert out.read_text() == docs.read_text(), "docs/dash.svg is stale: python tests/dash_helpers.py docs/dash.svg"
