"""arva-bench dash: widgets show exactly what the injected messages say; staleness follows
the clock; r records a session as arva-bench log does; help, quit; the reader threads
(reconnect, replay, scene truth) and the command line."""

from __future__ import annotations

import argparse
import asyncio
import json
import time

import pytest
from dash_helpers import DEFAULT_SLOTS, T0, FakeClock, default_scene_messages, inject, make_app, running_app, shown

from bench.cli import parse_args
from bench.dash import render
from bench.dash.app import HelpScreen
from bench.dash.cli import build_config
from bench.dash.messages import (
    AttitudeReceived,
    EpochReceived,
    FixReceived,
    LinkCounters,
    LinkStatus,
    TruthPose,
)
from bench.dash.recorder import SessionRecorder
from bench.dash.sources import DeviceFeed, LiveSource, ReplaySource, SceneTruth
from bench.dash.widgets import ChannelTable, DirectionIndicator, GroundTruthPanel, LinkPanel, ReceiverPanel, StatusBar
from bench.ingest.reader import Device, LinkEvent
from bench.logger import DeviceSpec
from bench.session import SessionWriter, read_jsonl, read_manifest, read_raw
from emulator.frames.geodesy import Origin, enu_to_geodetic
from firmware_proto.errors import InputError

pytestmark = pytest.mark.timeout(60)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, timeout=30))


def parva(seq: int, n: int, k: int, tx: int, d: int, delta: int) -> bytes:
    body = f"PARVA,{seq},{n},{k},{tx},{d},{delta}".encode()
    cs = 0
    for b in body:
        cs ^= b
    return b"$%s*%02X\r\n" % (body, cs)


# -- text art ------------------------------------------------------------------------------


DIAL_M89 = [
    "  +90°       0°      -90°",
    "         ····2····",
    "      ····       ····",
    "    ···             ···",
    "   ··                 ··",
    "   ·                   ·",
    "   ·         ▲─────────→",
]
DIAL_0 = [
    "  +90°       0°      -90°",
    "         ····↑····",
    "      ····   │   ····",
    "    ···      │      ···",
    "   ··        │        ··",
    "   ·         │         ·",
    "   ·         ▲         ·",
]
DIAL_45 = [
    "  +90°       0°      -90°",
    "         ····2····",
    "      ↖···       ····",
    "    ··╲╲╲           ···",
    "   ··   ╲╲╲           ··",
    "   ·      ╲╲╲          ·",
    "   ·        ╲▲         ·",
]


@pytest.mark.parametrize("delta, expected", [(-89, DIAL_M89), (0, DIAL_0), (45, DIAL_45)])
def test_dial_draws_delta_from_the_x_axis_positive_to_the_left(delta, expected):
    marks = [(2, 0)] if delta else []
    assert render.dial(delta, marks) == expected


def test_sparkline_scales_to_the_window_and_dots_missing_epochs():
    assert render.sparkline([100, 200, None, 800], 6) == "  ▁▂·█"
    assert render.sparkline([500] * 3, 3) == "▄▄▄"
    assert render.sparkline([1, 2, 3, 4, 5, 6, 7, 8, 9], 4) == "▁▃▆█"  # only the newest that fit


def test_a_long_url_keeps_its_end():
    from bench.dash.state import LinkView

    link = LinkView("arva", url="/media/field/campaigns/2026-01-15-slope-a/arva.raw")
    assert render.link_detail(link, 40) == "arva          0 B      0 …ope-a/arva.raw"


def test_truth_numbers_never_show_minus_zero():
    assert [render.num(v, 6, 2) for v in (-0.001, -0.0, 0.004, -0.005)] == ["  0.00", "  0.00", "  0.00", " -0.01"]


def test_zone_of_a_reported_slot():
    assert [render.zone(*s) for s in [(250, 0), (300, 0), (301, 0), (290, 5), (-1, -1)]] == [
        "inner", "inner", "mid", "mid", "—",
    ]  # fmt: skip


# -- the app with injected messages ------------------------------------------------------------


def test_channel_table_rows_and_dial_from_one_epoch(tmp_path):
    async def go():
        async with running_app(tmp_path, [EpochReceived("arva", "rx", 7, DEFAULT_SLOTS, T0)]) as (app, _):
            assert shown(app, ChannelTable) == [
                " id     d m   δ° zone   true m  err m  d(t)        ",
                "  4    7.61  -62 mid         —      —             ▄",
                "  2    9.26    0 mid         —      —             ▄",
                "  1   19.05   21 mid         —      —             ▄",
                "  3   28.08  -72 mid         —      —             ▄",
            ]
            dial = app.query_one(DirectionIndicator).plain.splitlines()
            assert dial[4] == "   ··              ╱╱╱↗3" and dial[-1] == "   tx 4  7.61 m  δ -62°"
            assert app.query_one(ReceiverPanel).border_title == "arva (rx)  seq 7"

    run(go())


def test_true_distance_and_error_of_d_from_scene_truth(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, default_scene_messages(3))
            rows = app.query_one(ChannelTable).plain.splitlines()
            assert rows[1:] == [
                "  4    7.61  -62 mid      7.81  -0.20           ▄▄▄",
                "  2    9.26    0 mid     10.05  -0.79           ▄▄▄",
                "  1   19.05   21 mid     20.62  -1.57           ▄▄▄",
                "  3   28.08  -72 mid     28.30  -0.22           ▄▄▄",
            ]
            assert app.query_one(GroundTruthPanel).plain.splitlines() == [
                "                  E m     N m    U m",
                "rx   scene       0.00    0.00   0.00",
                " hdg  90.0  roll    0.0  pitch   0.0",
                "tx1  scene      20.00    5.00   0.00",
                "tx2  scene      10.00    0.00   1.00",
                "tx3  scene      20.00  -20.00  -1.00",
                "tx4  scene      -6.00    5.00   0.00",
            ]

    run(go())


def test_empty_lost_and_inner_slots_and_the_d_history(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, [EpochReceived("arva", "rx", 0, [(1, 900, 10), (2, 1000, 5)], T0),
                                 EpochReceived("arva", "rx", 1, [(1, 700, 12), (-1, -1, -1)], T0 + 1),
                                 EpochReceived("arva", "rx", 3, [(1, 250, 0), None], T0 + 2, complete=False, gap=1)])  # fmt: skip
            assert app.query_one(ChannelTable).plain.splitlines()[1:] == [
                "  1    2.50    0 inner       —      —           █▆▁",
                "  ?    lost    — —           —      —              ",
            ]
            assert app.query_one(DirectionIndicator).plain.splitlines()[-1] == "tx 1  2.50 m  inner: no δ"
            panel = app.query_one(ReceiverPanel)
            assert (panel.border_title, panel.border_subtitle) == ("arva (rx)  seq 3", "incomplete epoch, 1 seq missing")

    run(go())


def test_links_rate_errors_and_stale_after_a_clock_advance(tmp_path):
    clock = FakeClock(T0 + 4.4)
    counters = LinkCounters(reads=10, bytes=520, records=5, checksum_errors=2, errors=3, seq_gaps=1,
                            dropped_bytes=57, last_data_mono=T0 + 4)  # fmt: skip

    async def go():
        messages = [EpochReceived("arva", "rx", k, DEFAULT_SLOTS, T0 + k) for k in range(5)]
        async with running_app(tmp_path, [*messages, LinkStatus("arva", "arva", "rx", "/dev/ttyUSB0", "up", counters)],
                               clock=clock) as (app, pilot):
            links = app.query_one(LinkPanel)
            assert shown(app, LinkPanel) == [
                "device   link  ep/s cks gap  last  drop",
                "arva     up     1.0   2   1  0.4s    57",
                "",
                "device      bytes reopen url",
                "arva        520 B      0 /dev/ttyUSB0",
            ]
            assert not app.query_one(ReceiverPanel).has_class("-stale")
            clock.now = T0 + 7.5  # 3.5 s of silence > --stale 3
            app.tick()
            await pilot.pause()
            assert links.plain.splitlines()[1] == "arva     STALE  0.0   2   1  3.5s    57"
            assert app.query_one(ReceiverPanel).has_class("-stale")
            await inject(pilot, [LinkStatus("arva", "arva", "rx", "/dev/ttyUSB0", "down", counters,
                                            "no data for 3 s: reopening")])  # fmt: skip
            assert links.plain.splitlines()[1:3] == [
                "arva     down   0.0   2   1  3.5s    57",
                "  no data for 3 s: reopening",
            ]
            await inject(pilot, [EpochReceived("arva", "rx", 8, DEFAULT_SLOTS, T0 + 7.5),
                                 LinkStatus("arva", "arva", "rx", "/dev/ttyUSB0", "up", counters)])  # fmt: skip
            assert links.plain.splitlines()[1] == "arva     up     0.7   2   1  0.0s    57"  # 6 epochs in 7.5 s
            assert not app.query_one(ReceiverPanel).has_class("-stale")

    run(go())


def test_rate_uses_the_sources_running_count_when_it_thins_records(tmp_path):
    async def go():
        app = make_app(tmp_path, clock=FakeClock(T0 + 2))
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, [EpochReceived("arva", "rx", k, DEFAULT_SLOTS, T0 + k, count=1 + 2500 * k)
                                 for k in range(3)])  # fmt: skip
            assert app.query_one(LinkPanel).plain.splitlines()[1] == "arva     wait  2500   0   0  0.0s     0"

    run(go())


def test_gps_truth_with_a_surveyed_transmitter(tmp_path):
    origin = Origin(46.5, 8.0, 2500.0)
    lat, lon, alt = (float(v) for v in enu_to_geodetic(3.0, 4.0, -1.0, origin))
    fix = {"sentence": "GGA", "talker": "GP", "time": "08:00:00", "lat": 46.5, "lon": 8.0, "alt_hae": 2500.0,
           "alt_msl": 2450.0, "quality": 1, "sats": 9, "hdop": 0.9, "status": None, "mode": None,
           "speed_knots": None, "course": None, "valid": True}  # fmt: skip

    async def go():
        app = make_app(tmp_path, tx_poses=[(1, [lat, lon, alt])])
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, [FixReceived("gps-rx", "rx", fix, T0),
                                 AttitudeReceived("attitude-rx", "rx", 90.0, 1.5, -2.25, [0.7071, 0, 0, 0.7071], T0),
                                 EpochReceived("arva", "rx", 0, [(1, 531, 12)], T0)])  # fmt: skip
            assert app.query_one(ChannelTable).plain.splitlines()[1] == (
                "  1    5.31   12 mid      5.10  +0.21             ▄"
            )
            assert app.query_one(GroundTruthPanel).plain.splitlines() == [
                "                  E m     N m    U m",
                "rx   gps         0.00    0.00   0.00",
                "     fix q1, 9 sats, hdop 0.9",
                " hdg  90.0  roll    1.5  pitch  -2.2",
                "tx1  surveyed    3.00    4.00  -1.00",
            ]
            names = [row.split()[0] for row in app.query_one(LinkPanel).plain.splitlines()[1:4]]
            assert names == ["arva", "gps-rx", "att-rx"]  # links seen only through their records

    run(go())


def test_a_device_nobody_announced_gets_its_own_panel(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, [EpochReceived("arva-rx2", "rx2", 3, [(5, 1200, -3)], T0)])
            panels = {p.device: p for p in app.query(ReceiverPanel)}
            assert set(panels) == {"arva", "arva-rx2"}
            assert panels["arva-rx2"].query_one(ChannelTable).plain.splitlines()[1].startswith(
                "  5   12.00   -3 mid"
            )

    run(go())


def test_a_receiver_with_many_channels_shows_them_all_and_brackets_stay_text(tmp_path):
    slots = [(i, 500 + 100 * i, i) for i in range(1, 10)]

    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 30)) as pilot:
            await inject(pilot, [EpochReceived("arva", "rx", 0, slots, T0)])
            table = app.query_one(ChannelTable)
            assert table.size.height == 10 and len(table.plain.splitlines()) == 10
            app.message = "recording stopped: [Errno 28] No space left on device"
            app.tick()
            await pilot.pause()
            assert str(app.query_one(StatusBar).visual).endswith("[Errno 28] No space left on device")

    run(go())


def test_help_screen_opens_and_closes(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("question_mark")
            assert isinstance(app.screen, HelpScreen)
            assert "start / stop recording" in str(app.screen.query_one("#help").content)
            await pilot.press("escape")
            assert not isinstance(app.screen, HelpScreen)
            await pilot.press("question_mark")
            await pilot.press("question_mark")
            assert not isinstance(app.screen, HelpScreen)

    run(go())


class _FakeSource:
    def __init__(self) -> None:
        self.calls: list[str] = []
        self.feeds: list = []

    def request_stop(self) -> None:
        self.calls.append("stop")

    def join(self, timeout: float) -> None:
        self.calls.append("join")


def test_q_quits_and_stops_the_sources(tmp_path):
    source = _FakeSource()

    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            app.sources = [source]
            await pilot.press("q")
            await pilot.pause()
        return app

    app = run(go())
    assert source.calls == ["stop", "join"]
    assert app.return_code == 0


def test_record_key_starts_and_stops_a_session(tmp_path):
    spec = DeviceSpec("arva", "arva", "arvaemu://", "rx")
    feed = DeviceFeed(spec, post=lambda m: None)
    source = _FakeSource()
    source.feeds = [feed]
    data = parva(0, 1, 1, 1, 1905, 21) + parva(1, 1, 1, 1, 1904, 21)

    async def go():
        app = make_app(tmp_path, specs=[spec], tx_poses=[(1, [46.5, 8.0, 2500.0])])
        async with app.run_test(size=(80, 24)) as pilot:
            app.sources = [source]
            assert str(app.query_one(StatusBar).content).endswith("○ not recording (r)")
            await pilot.press("r")
            assert feed.recorder is app.recorder is not None
            directory = app.recorder.directory
            assert directory.parent == tmp_path / "sessions"
            assert f"● REC {directory}" in str(app.query_one(StatusBar).content)
            assert app.query_one(StatusBar).has_class("-recording")
            deliver(feed, data[:20], 5.0, 1.7e9)  # as the reader thread does
            deliver(feed, data[20:], 5.1, 1.7e9 + 0.1)
            await pilot.press("r")
            assert feed.recorder is None and app.recorder is None
            assert str(app.query_one(StatusBar).content).endswith(f"saved {directory}")
        return directory

    directory = run(go())
    manifest = read_manifest(directory)
    assert manifest["devices"] == {"arva": {"kind": "arva", "url": "arvaemu://", "role": "rx", "baudrate": 115200}}
    assert manifest["tx_poses"] == {"1": {"lat": 46.5, "lon": 8.0, "alt": 2500.0}}
    assert "stop_utc" in manifest and manifest["summary"]["stopped_by"] == "user"
    assert b"".join(r.data for r in read_raw(directory / "arva.raw").reads) == data
    records = list(read_jsonl(directory / "arva.jsonl"))
    assert [(r["seq"], r["slots"]) for r in records] == [(0, [[1, 1905, 21]]), (1, [[1, 1904, 21]])]
    # Completed by the second read, len(parva(1)) bytes before its end (the stamp rule at 115200 Bd).
    assert records[0]["mono"] == round(5.1 - len(parva(1, 1, 1, 1, 1904, 21)) * 10 / 115200, 6)
    assert records[1]["mono"] == 5.1


def test_a_second_recording_gets_a_new_directory(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            dirs = []
            for _ in range(2):
                await pilot.press("r")
                dirs.append(app.recorder.directory)
                await pilot.press("r")
            return dirs

    first, second = run(go())
    assert first != second and (first / "manifest.json").exists() and (second / "manifest.json").exists()


def test_recording_to_an_unwritable_place_is_reported(tmp_path):
    (tmp_path / "sessions").write_text("a file, not a directory")

    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("r")
            assert app.recorder is None
            assert "cannot record" in str(app.query_one(StatusBar).content)

    run(go())


# -- reader threads -------------------------------------------------------------------------------


def deliver(feed, data, mono, utc):
    """One read, decoded by the feed's device, handed to the feed (as the reader thread does)."""
    feed.on_read(feed.device, feed.device.ingest(data, mono, utc))


class Collect:
    def __init__(self) -> None:
        self.messages: list = []

    def __call__(self, msg) -> None:
        self.messages.append(msg)

    def of(self, cls) -> list:
        return [m for m in list(self.messages) if isinstance(m, cls)]

    def wait(self, predicate, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise TimeoutError(f"condition not met; got {[type(m).__name__ for m in self.messages][-10:]}")
            time.sleep(0.02)


def test_feed_thins_a_flood_of_records_but_keeps_exact_counts():
    post = Collect()
    feed = DeviceFeed(DeviceSpec("arva", "arva", "x", "rx"), post)
    for k in range(1000):  # 1000 epochs in 1 s: far more than a UI draws
        deliver(feed, parva(k, 1, 1, 1, 1905, 21), 10.0 + k / 1000, 0.0)
    feed.stop()
    epochs = post.of(EpochReceived)
    assert 30 <= len(epochs) <= 60
    assert epochs[-1].seq == 999 and epochs[-1].count == 1000  # the latest always arrives, with the true count
    assert [e.count for e in epochs] == sorted(e.count for e in epochs)


def test_feed_counts_checksum_errors_gaps_and_dropped_bytes():
    post = Collect()
    feed = DeviceFeed(DeviceSpec("arva", "arva", "x", "rx"), post)
    bad = parva(1, 1, 1, 1, 1900, 21)
    bad = bad[:-4] + (b"00" if bad[-4:-2] != b"00" else b"11") + b"\r\n"
    deliver(feed, b"junk" + parva(0, 1, 1, 1, 1905, 21) + bad + parva(3, 1, 1, 1, 1890, 21), 1.0, 0.0)
    feed.status(force=True)
    c = post.of(LinkStatus)[-1].counters
    assert (c.records, c.checksum_errors, c.errors, c.seq_gaps, c.dropped_bytes) == (2, 1, 1, 1, 4 + len(bad))
    assert [m.seq for m in post.of(EpochReceived)] == [0, 3]
    assert post.of(EpochReceived)[1].gap == 2


def run_until(src, post, predicate):
    """Start the source ``src``; stop it once ``post`` has what ``predicate`` waits for."""
    src.start()
    try:
        post.wait(predicate)
    finally:
        src.request_stop()
        src.join(5)


def test_live_source_marks_an_unavailable_device_down_and_keeps_trying(tmp_path):
    post = Collect()
    src = LiveSource([DeviceFeed(DeviceSpec("arva", "arva", str(tmp_path / "no-such-tty"), "rx"), post)])
    run_until(src, post, lambda: any(m.state == "down" for m in post.of(LinkStatus)))
    assert not src.thread.is_alive()
    assert "no-such-tty" in post.of(LinkStatus)[-1].reason


def test_live_source_reopens_a_silent_device_by_itself():
    post = Collect()
    src = LiveSource([DeviceFeed(DeviceSpec("arva", "arva", "loop://", "rx"), post)], stale_after=0.3)
    run_until(src, post, lambda: any(m.counters.reconnects >= 2 for m in post.of(LinkStatus)))
    states = [m.state for m in post.of(LinkStatus)]
    assert states[:3] == ["up", "down", "up"]
    assert post.of(LinkStatus)[1].reason == "no data for 0.3 s: reopening"


def test_live_source_feeds_take_only_their_own_devices_reads_and_links():
    """The notifier tells every feed of every device: a GPS feed must not post the
    receiver's epochs as its own (nor hand them to a recording a second time)."""
    post = Collect()
    feeds = [DeviceFeed(DeviceSpec("arva", "arva", "arvaemu://?speed=0&frames=5", "rx"), post),
             DeviceFeed(DeviceSpec("gps-rx", "gps", "loop://", "rx"), post)]  # fmt: skip
    src = LiveSource(feeds, stale_after=5)

    def done() -> bool:  # five epochs, and the GPS link up
        gps_up = any(m.device == "gps-rx" and m.state == "up" for m in post.of(LinkStatus))
        return gps_up and len(post.of(EpochReceived)) >= 5

    run_until(src, post, done)
    epochs = post.of(EpochReceived)
    assert [(e.device, e.seq, e.count) for e in epochs] == [("arva", k, k + 1) for k in range(5)]
    assert feeds[1].counters().records == 0


def test_live_source_reads_the_in_process_emulator_with_scene_truth():
    post = Collect()
    spec = DeviceSpec("arva", "arva", "arvaemu://?speed=0&frames=3", "rx")
    src = LiveSource([DeviceFeed(spec, post, SceneTruth.for_url(spec.url, "rx"))], stale_after=5)
    run_until(src, post, lambda: len(post.of(EpochReceived)) >= 3)
    epochs = post.of(EpochReceived)
    assert [(e.seq, e.slots) for e in epochs] == [(k, DEFAULT_SLOTS) for k in range(3)]
    assert [e.count for e in epochs] == [1, 2, 3]
    truth = post.of(TruthPose)
    assert [t.role for t in truth] == ["rx", "tx1", "tx2", "tx3", "tx4"] * 3
    assert truth[3].position == (20.0, -20.0, -1.0) and truth[0].q == (1.0, 0.0, 0.0, 0.0)
    assert post.messages.index(truth[4]) < post.messages.index(epochs[0])  # truth before its epoch


def test_scene_truth_follows_a_moving_receiver(tmp_path):
    scene = tmp_path / "walk.toml"
    scene.write_text(
        "spec = 1\nrate_hz = 2.0\n[[transmitters]]\nid = 1\nposition = [0.0, 0.0, 0.0]\n"
        "[receiver]\nchannels = 1\npath = [{ t = 0.0, position = [10.0, 0.0, 0.0] },"
        " { t = 10.0, position = [0.0, 0.0, 0.0] }]\n"
    )
    truth = SceneTruth.for_url(f"arvaemu://{scene}", "rx")
    ks = [truth.on_epoch(4), truth.on_epoch(65535), truth.on_epoch(2)]  # seq wraps after 65535
    assert ks == [4, 65535, 65538]
    truth.reset()  # a new connection: the emulator starts again at epoch 0
    assert truth.on_epoch(6) == 6
    rx = [truth.poses(k, 0.0)[0].position for k in (4, 65535, 6)]
    assert rx[0] == pytest.approx((8.0, 0.0, 0.0))  # t = 2 s
    assert rx[1] == pytest.approx((0.0, 0.0, 0.0))  # long past the end of the path: its last pose holds
    assert rx[2] == pytest.approx((7.0, 0.0, 0.0))
    assert SceneTruth.for_url("/dev/ttyUSB0", "rx") is None


def _session(path):
    w = SessionWriter(path, {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"},
                                         "attitude-rx": {"kind": "attitude", "url": "y", "role": "rx"}},
                             "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2500.0}}})  # fmt: skip
    for k in range(4):
        w.raw("arva", parva(k, 1, 1, 1, 1905 - k, 21), mono=50.0 + 0.1 * k, utc=0.0)
    w.raw("attitude-rx", b"$PASHR,080000.000,123.40,T,+01.50,-02.00,+00.00,0.050,0.050,0.100,1,1*06\r\n", mono=50.05, utc=0.0)
    w.close()


def test_replay_source_feeds_a_session_with_its_timing(tmp_path):
    _session(tmp_path / "s")
    post = Collect()
    feeds = [DeviceFeed(DeviceSpec("arva", "arva", "x", "rx"), post),
             DeviceFeed(DeviceSpec("attitude-rx", "attitude", "y", "rx"), post)]  # fmt: skip
    src = ReplaySource(tmp_path / "s", feeds, speed=1.0)
    t0 = time.monotonic()
    src.start()
    post.wait(lambda: sum(m.state == "ended" for m in post.of(LinkStatus)) == 2)
    elapsed = time.monotonic() - t0
    src.join(5)
    assert [(e.seq, e.slots) for e in post.of(EpochReceived)] == [(k, [(1, 1905 - k, 21)]) for k in range(4)]
    assert 0.25 <= elapsed < 5  # the last read is 0.3 s after the first
    kinds = [type(m).__name__ for m in post.messages if not isinstance(m, LinkStatus)]
    assert kinds[:3] == ["EpochReceived", "AttitudeReceived", "EpochReceived"]  # interleaved by the log's clock


def test_replay_source_with_a_corrupt_log_shows_every_link_down_with_the_line(tmp_path):
    _session(tmp_path / "s")
    with open(tmp_path / "s" / "arva.raw", "ab") as f:
        f.write(b"not a raw line\n1.0\t2026-01-01T00:00:00.000000Z\t\n")  # a bad line, then a good one
    post = Collect()
    feeds = [DeviceFeed(DeviceSpec("arva", "arva", "x", "rx"), post),
             DeviceFeed(DeviceSpec("attitude-rx", "attitude", "y", "rx"), post)]  # fmt: skip
    src = ReplaySource(tmp_path / "s", feeds, speed=0)
    src.start()
    src.join(10)
    assert not src.is_alive()
    down = [(m.device, m.reason) for m in post.of(LinkStatus) if m.state == "down"]
    why = f"{tmp_path / 's' / 'arva.raw'}: line 5: not a raw record " \
          "(not enough values to unpack (expected 3, got 1))"
    assert down == [("arva", why), ("attitude-rx", why)]
    assert post.of(EpochReceived) == []


def test_recorder_writes_what_a_logger_would(tmp_path):
    spec = DeviceSpec("gps-rx", "gps", "loop://", "rx")
    rec = SessionRecorder(tmp_path / "s", [spec], {"devices": {"gps-rx": spec.manifest()}})
    dev = Device(spec)
    rec.on_read(dev, dev.ingest(b"$GPGGA,080000.00,4630.00000,N,00800.00000,E,1,09,0.9,2450.0,M,50.0,M,,*", 1.0, 1.7e9))
    rec.on_link(dev, LinkEvent("gap", 2.0, "unplugged"))
    rec.close()
    assert read_raw(tmp_path / "s" / "gps-rx.raw").reads[0].mono == 1.0
    events = [json.loads(line)["event"] for line in (tmp_path / "s" / "events.jsonl").read_text().splitlines()]
    assert events == ["start", "gap", "stop"]
    assert read_manifest(tmp_path / "s")["summary"]["devices"]["gps-rx"]["gaps"] == 1


# -- command line -------------------------------------------------------------------------------------


def config_of(*argv):
    return build_config(parse_args(["dash", *argv]), argv=["arva-bench", "dash", *argv])


def test_no_source_is_the_in_process_emulator_with_scene_truth(tmp_path):
    cfg = config_of()
    assert [(s.name, s.kind, s.url, s.role) for s in cfg.specs] == [("arva", "arva", "arvaemu://", "rx")]
    assert cfg.scene_truth and cfg.replay is None


def test_sources_and_roles_as_in_log():
    cfg = config_of("/dev/ttyUSB0", "arvaemu://?receiver=2,role=rx2", "--gps", "/dev/ttyACM0,role=tx1",
                    "--tx-pose", "2=46.5,8.0,2500")  # fmt: skip
    assert [(s.name, s.kind, s.role) for s in cfg.specs] == [
        ("arva-rx1", "arva", "rx1"), ("arva-rx2", "arva", "rx2"), ("gps-tx1", "gps", "tx1"),
    ]  # fmt: skip
    assert not cfg.scene_truth  # real ground truth given: the scene's is not mixed in
    assert cfg.tx_poses == [(2, [46.5, 8.0, 2500.0])]


def test_a_session_directory_is_replayed_with_its_truth(tmp_path):
    _session(tmp_path / "s")
    cfg = config_of(str(tmp_path / "s"), "--speed", "4")
    assert cfg.replay == tmp_path / "s" and cfg.replay_speed == 4.0
    assert [(s.name, s.kind) for s in cfg.specs] == [("arva", "arva"), ("attitude-rx", "attitude")]
    assert cfg.tx_poses == [(1, [46.5, 8.0, 2500.0])]
    with pytest.raises(InputError, match="only source"):
        config_of(str(tmp_path / "s"), "loop://")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="not a session directory"):
        config_of(str(tmp_path / "empty"))


def test_argument_errors():
    with pytest.raises(InputError, match="dash: two devices would both be 'gps-rx'"):
        config_of("--gps", "loop://", "--gps", "loop://")
    with pytest.raises(SystemExit):  # cli_types.positive_seconds: argparse refuses it
        config_of("--stale", "0")
    with pytest.raises(SystemExit):
        parse_args(["dash", "loop://,role=boat"])
    assert isinstance(parse_args(["dash"]), argparse.Namespace)


def test_n_and_p_bring_each_receiver_into_view_at_80x24(tmp_path):
    specs = [DeviceSpec(f"arva-rx{i}", "arva", f"arvaemu://?receiver={i}", f"rx{i}") for i in (1, 2, 3)]

    async def go():
        app = make_app(tmp_path, specs=specs)
        async with app.run_test(size=(80, 24)) as pilot:
            await inject(pilot, [EpochReceived(s.name, s.role, 0, [(1, 500, 3)], T0) for s in specs])
            box = app.query_one("#receivers")
            panels = list(app.query(ReceiverPanel))

            def in_view():
                return [p.device for p in panels if box.region.contains_region(p.region)]

            assert in_view() == ["arva-rx1"] and str(app.query_one(StatusBar).visual).startswith(
                " arva-bench dash · 3 receivers (n/p)"
            )
            for key, device in [("n", "arva-rx2"), ("n", "arva-rx3"), ("n", "arva-rx1"), ("p", "arva-rx3")]:
                await pilot.press(key)
                await pilot.pause()
                assert in_view() == [device], key

    run(go())


def test_scene_truth_reads_the_url_as_the_port_does(scene_file):
    """Through the port's own parse_url: a URL the port refuses gives no scene truth (the
    port reports the problem), never the first receiver's poses."""
    from scene_builders import two_rx

    scene = scene_file(two_rx(channels_7=2), "two.toml")
    truth = SceneTruth.for_url(f"arvaemu://{scene}?receiver=7", "rx")
    assert truth is not None and truth.rx.id == 7
    assert SceneTruth.for_url(f"arvaemu://{scene}?receiver=9", "rx") is None
    assert SceneTruth.for_url("arvaemu://?speed=fast", "rx") is None
    assert SceneTruth.for_url("socket://localhost:1", "rx") is None
