"""arva-bench dash layout at sizes other than the 80x24 snapshots: the receiver panels
and the ground-truth / link panels share the height, with no empty rows between them."""

from __future__ import annotations

import asyncio

import pytest
from dash_helpers import inject, make_app, walk_app, walk_messages

from bench.dash.widgets import ReceiverPanel
from bench.logger import DeviceSpec

pytestmark = pytest.mark.timeout(60)


async def regions(app, size, messages=()):
    async with app.run_test(size=size) as pilot:
        if messages:
            await inject(pilot, list(messages))
        await pilot.pause()
        panels = [p.region for p in app.query(ReceiverPanel)]
        return app.query_one("#receivers").region, panels, app.query_one("#bottom").region


@pytest.mark.parametrize("size", [(80, 24), (100, 30), (100, 40)])
def test_one_receiver_leaves_no_empty_rows(tmp_path, size):
    receivers, panels, bottom = asyncio.run(regions(walk_app(tmp_path), size, walk_messages()))
    assert len(panels) == 1
    assert receivers.height == panels[0].height == 10  # the panel's own height, no gap below it
    assert bottom.y == receivers.y + receivers.height  # the bottom panels start right there
    assert bottom.y + bottom.height == size[1] - 1  # and take every row down to the footer
    assert bottom.height == size[1] - 2 - 10


@pytest.mark.parametrize("size", [(80, 24), (100, 30)])
def test_more_receivers_than_fit_scroll_above_full_bottom_panels(tmp_path, size):
    specs = [DeviceSpec(f"arva{i}", "arva", f"/dev/ttyUSB{i}", f"rx{i}") for i in range(3)]
    receivers, panels, bottom = asyncio.run(regions(make_app(tmp_path, specs=specs), size))
    assert len(panels) == 3
    assert bottom.height == 12  # the minimum; the receivers scroll in what is left
    assert receivers.height == size[1] - 2 - 12
    assert bottom.y == receivers.y + receivers.height
