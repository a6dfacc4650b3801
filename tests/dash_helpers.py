"""Shared by the dashboard tests: a fixed clock, an app without source threads, and the
default scene's epoch as the emulator sends it."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from bench.dash.app import DashApp, DashConfig
from bench.dash.messages import EpochReceived, LinkCounters, LinkStatus, TruthPose
from bench.logger import DeviceSpec

#: Epoch 0 of the embedded default scene (the paper's four transmitters), slot order.
DEFAULT_SLOTS = [(4, 761, -62), (2, 926, 0), (1, 1905, 21), (3, 2808, -72)]
#: Their positions in the scene (ENU m); the receiver sits at the origin.
DEFAULT_TX = {1: (20.0, 5.0, 0.0), 2: (10.0, 0.0, 1.0), 3: (20.0, -20.0, -1.0), 4: (-6.0, 5.0, 0.0)}
T0 = 1000.0


class FakeClock:
    def __init__(self, now: float = T0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def make_app(tmp_path, specs=None, clock=None, **config) -> DashApp:
    specs = specs if specs is not None else [DeviceSpec("arva", "arva", "arvaemu://", "rx")]
    cfg = DashConfig(specs=specs, start_sources=False, record_dir=tmp_path / "sessions", argv=["arva-bench", "dash"],
                     **config)  # fmt: skip
    return DashApp(cfg, clock=clock or FakeClock(), tick=None)


def default_scene_messages(epochs: int = 1, t0: float = T0, rate: float = 1.0, truth: bool = True) -> list:
    """What an arvaemu:// source on the default scene posts for ``epochs`` epochs."""
    out: list = []
    for k in range(epochs):
        mono = t0 + k / rate
        if truth:
            out.append(TruthPose("rx", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), "scene", mono))
            if k == 0:
                out += [TruthPose(f"tx{i}", p, (1.0, 0.0, 0.0, 0.0), "scene", mono) for i, p in DEFAULT_TX.items()]
        out.append(EpochReceived("arva", "rx", k, DEFAULT_SLOTS, mono))
    out.append(
        LinkStatus("arva", "arva", "rx", "arvaemu://", "up",
                   LinkCounters(reads=2 * epochs, bytes=104 * epochs, records=epochs, last_data_mono=t0 + (epochs - 1) / rate))
    )  # fmt: skip
    return out


async def inject(pilot, messages) -> None:
    for msg in messages:
        pilot.app.post_message(msg)
    await pilot.pause()


@contextlib.asynccontextmanager
async def running_app(tmp_path, messages, size=(80, 24), **kw) -> AsyncIterator[tuple[DashApp, object]]:
    """``make_app(tmp_path, **kw)`` running headless at ``size`` with ``messages`` injected:
    yields (app, pilot)."""
    app = make_app(tmp_path, **kw)
    async with app.run_test(size=size) as pilot:
        await inject(pilot, messages)
        yield app, pilot


def shown(app, widget) -> list[str]:
    """The lines the app's ``widget`` (a widget class) shows."""
    return app.query_one(widget).plain.splitlines()


#: A walk past the default scene's transmitters: (receiver position, yaw in degrees, slots),
#: the slots as the receiver model gives them there (computed once, kept literal so the
#: snapshots do not depend on the model's code).
WALK = [
    ((-4.0, 1.0, 0.0), 0, [(4, 478, 72), (2, 1294, -6), (1, 2239, 14), (3, 3125, -65)]),
    ((-3.25, 1.25, 0.0), 3, [(4, 477, 89), (2, 1229, -11), (1, 2166, 11), (3, 3099, -70)]),
    ((-2.5, 1.5, 0.0), 6, [(4, 491, -78), (2, 1164, -16), (1, 2094, 7), (3, 3075, -75)]),
    ((-1.75, 1.75, 0.0), 9, [(4, 518, -67), (2, 1100, -22), (1, 2022, 4), (3, 3053, -81)]),
    ((-1.0, 2.0, 0.0), 12, [(4, 555, -60), (2, 1038, -28), (1, 1950, 0), (3, 3033, -86)]),
    ((-0.25, 2.25, 0.0), 15, [(4, 599, -54), (2, 977, -34), (1, 1878, -3), (3, 3015, 88)]),
    ((0.5, 2.5, 0.0), 18, [(4, 650, -50), (2, 918, -40), (1, 1806, -7), (3, 3000, 83)]),
    ((1.25, 2.75, 0.0), 21, [(4, 704, -47), (2, 861, -48), (1, 1735, -11), (3, 2986, 77)]),
    ((2.0, 3.0, 0.0), 24, [(4, 762, -45), (2, 807, -55), (1, 1663, -14), (3, 2975, 71)]),
    ((2.75, 3.25, 0.0), 27, [(2, 757, -64), (4, 822, -44), (1, 1592, -18), (3, 2967, 66)]),
    ((3.5, 3.5, 0.0), 30, [(2, 710, -74), (4, 885, -43), (1, 1521, -22), (3, 2961, 60)]),
    ((4.25, 3.75, 0.0), 33, [(2, 670, -85), (4, 949, -43), (1, 1450, -26), (3, 2957, 53)]),
]


def _yaw_q(deg: float) -> tuple[float, float, float, float]:
    import math

    half = math.radians(deg) / 2
    return (math.cos(half), 0.0, 0.0, math.sin(half))


def walk_messages(t0: float = T0) -> list:
    """The walk as an arvaemu:// source would post it (scene truth, epochs, link)."""
    out: list = []
    for k, (pos, yaw, slots) in enumerate(WALK):
        mono = t0 + k
        out.append(TruthPose("rx", pos, _yaw_q(yaw), "scene", mono))
        if k == 0:
            out += [TruthPose(f"tx{i}", p, (1.0, 0.0, 0.0, 0.0), "scene", mono) for i, p in DEFAULT_TX.items()]
        out.append(EpochReceived("arva", "rx", 40 + k, slots, mono))
    last = t0 + len(WALK) - 1
    out.append(LinkStatus("arva", "arva", "rx", "arvaemu://", "up",
                          LinkCounters(reads=24, bytes=1248, records=12, last_data_mono=last)))  # fmt: skip
    return out


def walk_app(tmp_path) -> DashApp:
    """The app after the walk, 0.4 s after its last epoch (what the docs screenshot shows)."""
    return make_app(tmp_path, clock=FakeClock(T0 + len(WALK) - 1 + 0.4))


async def save_walk_screenshot(path: str, tmp_path) -> None:
    app = walk_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await inject(pilot, walk_messages())
        app.save_screenshot(filename=path)


if __name__ == "__main__":  # regenerate docs/dash.svg: python tests/dash_helpers.py docs/dash.svg
    import asyncio
    import sys
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        asyncio.run(save_walk_screenshot(str(Path(sys.argv[1]).resolve()), Path(tmp)))
