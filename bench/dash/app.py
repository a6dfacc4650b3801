"""``DashApp``: the live terminal view of receivers, ground truth and links.

State is updated only by message handlers on the UI thread; source threads post
:mod:`bench.dash.messages` with ``post_message``. ``clock`` (default ``time.monotonic``,
the clock the sources stamp reads with) gives "now" for data ages and staleness, so tests
and snapshots inject a fixed one.

Keys: ``r`` starts / stops recording a session (``--record-dir``), ``?`` help, ``q`` quit.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from textual import events
from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Footer, Static

from emulator.frames.geodesy import Origin
from firmware_proto.errors import InputError

from ..log import manifest
from ..logger import DeviceSpec
from .messages import AttitudeReceived, EpochReceived, FixReceived, LinkStatus, TruthPose
from .recorder import SessionRecorder
from .state import LinkView, ReceiverState, TruthState
from .widgets import (ChannelTable, ChannelView, DirectionIndicator, GroundTruthPanel, LinkPanel, LinksView,
                      ReceiverPanel, StatusBar, TruthView)

HELP = """\
[b]arva-bench dash[/b]: receivers, ground truth and links, live
[b]r[/b]  start / stop recording a session (as arva-bench log)
[b]n p[/b] next / previous receiver panel, when there are several
[b]?[/b]  this help (esc or ? closes it)    [b]q[/b]  quit

[b]Receiver[/b] (latest epoch, one panel per receiver)
  id d δ    transmitter, distance (m), direction (deg)
  zone      inner (d <= 3 m, no δ), mid; — an empty slot
  true err  true distance (ground truth); d - true
  d(t)      d per epoch, newest on the right; · not heard
  dial      δ of the nearest channel, receiver x axis up,
            δ > 0 to the left (toward y); others' ids

[b]Links[/b]
  ep/s      epochs (GPS fixes, attitudes) per second
  cks gap   checksum errors; seq gaps (receivers)
  last      time since the last data
  drop      bytes dropped (junk, rejected sentences)
  STALE     silent longer than --stale; reopened by itself"""


@dataclass
class DashConfig:
    """What the dashboard shows and reads; built by ``arva-bench dash`` (or a test)."""

    specs: list[DeviceSpec] = field(default_factory=list)
    replay: Path | None = None  # a session directory whose devices are ``specs``
    replay_speed: float = 1.0
    origin: list[float] | None = None
    tx_poses: list[tuple[int, list[float]]] = field(default_factory=list)
    scene_truth: bool = True
    stale_after: float = 3.0
    record_dir: Path = Path("sessions")
    argv: list[str] = field(default_factory=list)
    note: str = "recorded with arva-bench dash"
    start_sources: bool = True


class HelpScreen(ModalScreen):
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "dismiss", "Close"),
                                             Binding("question_mark", "dismiss", "Close")]

    def compose(self) -> ComposeResult:
        yield Static(HELP, id="help")


#: The ground-truth and link panels' minimum height (``#bottom`` in dash.tcss).
BOTTOM_MIN_ROWS = 12


class DashApp(App):
    CSS_PATH = "dash.tcss"
    TITLE = "arva-bench dash"
    ENABLE_COMMAND_PALETTE = False
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("r", "record", "Record"),
        Binding("n", "receiver(1)", "Next rx", show=False),
        Binding("p", "receiver(-1)", "Prev rx", show=False),
        Binding("question_mark", "help", "Help", key_display="?"),
        Binding("q", "quit", "Quit"),
        Binding("ctrl+c", "quit", "Quit", show=False, priority=True),
    ]

    def __init__(self, config: DashConfig, clock: Callable[[], float] = time.monotonic,
                 tick: float | None = 0.5) -> None:
        super().__init__()
        self.config = config
        self.clock = clock
        self._tick = tick
        self.truth = TruthState(Origin(*config.origin) if config.origin else None, dict(config.tx_poses))
        self.receivers: dict[str, ReceiverState] = {}
        self.links: dict[str, LinkView] = {}
        for spec in config.specs:
            self.links[spec.name] = LinkView(spec.name, spec.kind, spec.role, spec.url)
            if spec.kind == "arva":
                self.receivers[spec.name] = ReceiverState(spec.name, spec.role)
        self.sources: list = []
        self.recorder: SessionRecorder | None = None
        self.last_session: Path | None = None
        self.message = ""
        self._shut = False
        self._rx_index = 0  # the receiver panel n / p last brought into view

    # -- layout ----------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield StatusBar(self._status_text(), id="status")
        with VerticalScroll(id="receivers"):
            for rs in self.receivers.values():
                yield ReceiverPanel(rs.device, rs.role)
        with Horizontal(id="bottom"):
            yield GroundTruthPanel(id="truth")
            yield LinkPanel(id="links")
        yield Footer()

    def on_resize(self, event: events.Resize) -> None:
        # Receivers take the rows they need, at most what leaves the status bar, the
        # footer and the bottom panels' minimum (dash.tcss); the bottom takes the rest.
        self.query_one("#receivers").styles.max_height = max(10, event.size.height - 2 - BOTTOM_MIN_ROWS)

    def on_mount(self) -> None:
        self._refresh_truth()
        self._refresh_links()
        for rs in self.receivers.values():
            self._refresh_receiver(rs)
        if self._tick:
            self.set_interval(self._tick, self.tick)
        if self.config.start_sources:
            # Imported here, once the screen is up: the sources pull in the emulator
            # (scenes, scipy) for arvaemu:// and scene truth, about a second of imports
            # the terminal would otherwise wait through. (sources imports nothing of app.)
            from .sources import start_sources

            self.sources = start_sources(self.config, self.post_message)

    # -- messages from the source threads ---------------------------------------------------
    async def on_epoch_received(self, msg: EpochReceived) -> None:
        rs = self.receivers.get(msg.device)
        if rs is None:  # a device nobody announced (a test, or a replayed session's extra)
            rs = self.receivers[msg.device] = ReceiverState(msg.device, msg.role)
            await self.query_one("#receivers").mount(ReceiverPanel(msg.device, msg.role))
        rs.on_epoch(msg.seq, msg.slots, msg.complete)
        self._link(msg.device, "arva", msg.role).arrived(msg.mono, msg.count)
        self._refresh_receiver(rs, gap=msg.gap)
        self._refresh_links()

    def on_fix_received(self, msg: FixReceived) -> None:
        self.truth.on_fix(msg.role, msg.fix)
        link = self._link(msg.device, "gps", msg.role)
        sentence = msg.fix.get("sentence")
        link.seen_gga |= sentence == "GGA"
        if sentence == "GGA" or not link.seen_gga:
            link.arrived(msg.mono, msg.count)  # one fix per GGA (RMC only when a device sends no GGA)
        self._refresh_truth()
        self._refresh_links()

    def on_attitude_received(self, msg: AttitudeReceived) -> None:
        self.truth.on_attitude(msg.role, msg.heading, msg.roll, msg.pitch, msg.q)
        self._link(msg.device, "attitude", msg.role).arrived(msg.mono, msg.count)
        self._refresh_truth()
        self._refresh_links()

    def on_truth_pose(self, msg: TruthPose) -> None:
        self.truth.on_pose(msg.role, msg.position, msg.q, msg.via)
        self._refresh_truth()

    def on_link_status(self, msg: LinkStatus) -> None:
        link = self._link(msg.device, msg.kind, msg.role)
        link.url = msg.url
        if msg.state != link.state:
            link.state_since = self.clock()
        link.state, link.reason, link.counters = msg.state, msg.reason, msg.counters
        self._refresh_links()

    def _link(self, device: str, kind: str, role: str) -> LinkView:
        return self.links.setdefault(device, LinkView(device, kind, role))

    # -- drawing -------------------------------------------------------------------------------
    def _refresh_receiver(self, rs: ReceiverState, gap: int = 0) -> None:
        panel = next((p for p in self.query(ReceiverPanel) if p.device == rs.device), None)
        if panel is None or not panel.children:
            return
        ids = [s[0] for s in rs.slots if s is not None and s[0] >= 0]
        panel.query_one(ChannelTable).view = ChannelView(tuple(rs.slots), self.truth.distances(rs.role, ids), rs.histories())
        panel.query_one(DirectionIndicator).slots = tuple(rs.slots)
        panel.show(rs.seq, rs.complete, gap)

    def _refresh_truth(self) -> None:
        self.query_one(GroundTruthPanel).view = TruthView(dict(self.truth.poses), tuple(self.truth.roles()))
        for rs in self.receivers.values():
            if rs.slots:
                self._refresh_receiver(rs)

    def _refresh_links(self) -> None:
        now = self.clock()
        self.query_one(LinkPanel).view = LinksView(tuple(self.links.values()), now, self.config.stale_after)
        for panel in self.query(ReceiverPanel):
            link = self.links.get(panel.device)
            panel.set_class(link is not None and link.stale(now, self.config.stale_after), "-stale")

    def action_receiver(self, step: int) -> None:
        """Bring the next (step 1) or previous (-1) receiver panel to the top of the view."""
        panels = list(self.query(ReceiverPanel))
        if len(panels) < 2:
            return
        self._rx_index = (self._rx_index + step) % len(panels)
        self.query_one("#receivers", VerticalScroll).scroll_to_widget(panels[self._rx_index], animate=False, top=True)

    def _status_text(self) -> str:
        n = len(self.receivers)
        left = f" arva-bench dash · {n} receiver{'s' if n != 1 else ''}" + (" (n/p)" if n > 1 else "")
        if self.recorder is not None:
            kb = self.recorder.writer.bytes_on_disk() / 1000
            right = f"● REC {self.recorder.directory}  {kb:.1f} kB"
        else:
            right = "○ not recording (r)"
        return " │ ".join(filter(None, [left, right, self.message]))

    def _refresh_status(self) -> None:
        bar = self.query_one(StatusBar)
        bar.update(self._status_text())
        bar.set_class(self.recorder is not None, "-recording")

    def tick(self) -> None:
        """Periodic: data ages, staleness, the recording's size and disk errors."""
        if self.recorder is not None and self.recorder.error is not None:
            error = self.recorder.error
            self._stop_recording()
            self.message = f"recording stopped: {error}"
        self._refresh_links()
        self._refresh_status()

    # -- actions -----------------------------------------------------------------------------------
    def action_help(self) -> None:
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen())

    def action_record(self) -> None:
        if self.recorder is not None:
            self._stop_recording()
            self.message = f"saved {self.last_session}"
        else:
            self._start_recording()
        self._refresh_status()

    def _new_session_dir(self) -> Path:
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        base = Path(self.config.record_dir) / stamp
        path, n = base, 1
        while path.exists():
            n += 1
            path = base.with_name(f"{stamp}-{n}")
        return path

    def _manifest(self) -> dict:
        args = argparse.Namespace(note=self.config.note, origin=self.config.origin, tx_pose=self.config.tx_poses)
        out = manifest(args, self.config.specs, self.config.argv)
        if self.config.replay is not None:
            out["replayed_from"] = str(self.config.replay)
        return out

    def _start_recording(self) -> None:
        try:
            recorder = SessionRecorder(self._new_session_dir(), self.config.specs, self._manifest())
        except (InputError, OSError) as exc:
            self.message = f"cannot record: {exc}"
            return
        self.recorder = recorder
        self._attach(recorder)
        self.message = ""

    def _stop_recording(self) -> None:
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            self._attach(None)
            recorder.close()
            self.last_session = recorder.directory

    def _attach(self, recorder: SessionRecorder | None) -> None:
        """Every feed hands its reads to ``recorder`` (None: to nobody)."""
        for source in self.sources:
            for feed in source.feeds:
                feed.recorder = recorder

    async def action_quit(self) -> None:
        self.shutdown()
        self.exit()

    def shutdown(self) -> None:
        """Close a recording, stop the source threads (idempotent)."""
        if self._shut:
            return
        self._shut = True
        self._stop_recording()
        for source in self.sources:
            source.request_stop()
        deadline = time.monotonic() + 2.0
        for source in self.sources:
            source.join(max(0.0, deadline - time.monotonic()))

    def on_unmount(self) -> None:
        self.shutdown()
