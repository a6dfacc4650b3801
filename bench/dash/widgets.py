"""The dashboard's widgets. Each holds what it shows in one reactive attribute (a frozen
dataclass: assigning it repaints the widget, no manual refresh) and renders it with the
text-art functions of :mod:`bench.dash.render` at its current width; ``plain`` is the
exact text shown (what the tests compare). Colours and layout are in ``dash.tcss``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from rich.text import Text
from textual.containers import Horizontal
from textual.reactive import reactive
from textual.widget import Widget
from textual.widgets import Static

from . import render
from .state import LinkView, Pose


@dataclass(frozen=True)
class ChannelView:
    """A receiver's slots ``(id, d, delta)`` or None, true distances by id (m), and each
    channel's d history."""

    slots: tuple = ()
    true_m: dict[int, float] = field(default_factory=dict)
    histories: dict[int, list] = field(default_factory=dict)


@dataclass(frozen=True)
class TruthView:
    """Poses by role, and the roles in display order."""

    poses: dict[str, Pose] = field(default_factory=dict)
    roles: tuple[str, ...] = ()


@dataclass(frozen=True)
class LinksView:
    """Every device link, the app clock's ``now`` and the ``--stale`` limit (s)."""

    links: tuple[LinkView, ...] = ()
    now: float = 0.0
    stale_after: float = 3.0


def _css_id(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


class _TextWidget(Widget):
    """A widget whose content is lines of text computed from its data and width."""

    DEFAULT_WIDTH = 40

    def _width(self) -> int:
        return self.content_size.width or self.DEFAULT_WIDTH

    def lines(self, width: int) -> list[str]:
        raise NotImplementedError

    @property
    def plain(self) -> str:
        return "\n".join(self.lines(self._width()))

    def render(self) -> Text:
        return Text("\n".join(self.lines(self._width())), no_wrap=True, overflow="crop")


class ChannelTable(_TextWidget):
    """id, d (m), δ (deg), zone, true distance and error of d (when ground truth knows
    both devices), and a d-versus-time sparkline per channel (newest epoch on the right)."""

    DEFAULT_WIDTH = 50
    view: reactive[ChannelView] = reactive(ChannelView, always_update=True)

    def lines(self, width: int) -> list[str]:
        v = self.view
        if not v.slots:
            return [render.table_header(width), "waiting for the first epoch"[:width]]
        return render.channel_rows(list(v.slots), v.true_m, v.histories, width)


class DirectionIndicator(_TextWidget):
    """δ of the nearest channel (slot 1) as a ray on a half dial, the receiver's x axis
    up and its y axis (δ > 0) to the left; the other channels' ids on the arc; below,
    the transmitter, its distance and δ."""

    DEFAULT_WIDTH = 26
    slots: reactive[tuple] = reactive(tuple, always_update=True)

    def lines(self, width: int) -> list[str]:
        def directed(s) -> bool:  # a transmitter heard in the mid zone (zone() is "mid" only for d >= 0)
            return s is not None and s[0] >= 0 and render.zone(s[1], s[2]) == "mid"

        first = self.slots[0] if self.slots else None
        delta = first[2] if directed(first) else None
        marks = [(s[0], s[2]) for s in self.slots[1:] if directed(s)]
        caption = render.dial_caption(first)  # "no epoch yet" without one
        return render.dial(delta, marks, width=width) + [caption.center(width).rstrip()[:width]]


class ReceiverPanel(Horizontal):
    """One receiver: its channel table and direction indicator under a titled border."""

    def __init__(self, device: str, role: str) -> None:
        super().__init__(id=f"rx-{_css_id(device)}", classes="receiver")
        self.device = device
        self.role = role
        self.border_title = f"{device} ({role})"

    def compose(self):
        yield ChannelTable(classes="channels")
        yield DirectionIndicator(classes="direction")

    def show(self, seq: int | None, complete: bool, gap: int) -> None:
        """The title with the latest epoch's seq; below, an incomplete epoch or missing seqs."""
        self.border_title = f"{self.device} ({self.role})" + ("" if seq is None else f"  seq {seq}")
        notes = [] if complete else ["incomplete epoch"]
        if gap:
            notes.append(f"{gap} seq missing")
        self.border_subtitle = ", ".join(notes)


class GroundTruthPanel(_TextWidget):
    """Per role (rx, tx<ID>): position in ENU metres and how it is known (GPS fix
    quality, surveyed, scene), and attitude (heading, roll, pitch in degrees)."""

    DEFAULT_WIDTH = 36
    BORDER_TITLE = "ground truth"
    view: reactive[TruthView] = reactive(TruthView, always_update=True)

    def lines(self, width: int) -> list[str]:
        return render.truth_lines(self.view.poses, list(self.view.roles), width)


class LinkPanel(_TextWidget):
    """One row per device: state, records/s, checksum errors, seq gaps, time since the
    last data, bytes dropped; a down link's reason below it. Then each device's URL,
    bytes read and how often it was reopened."""

    DEFAULT_WIDTH = 40
    BORDER_TITLE = "links"
    COMPONENT_CLASSES: ClassVar[set[str]] = {"link--up", "link--STALE", "link--down", "link--end", "link--wait", "link--header"}

    view: reactive[LinksView] = reactive(LinksView, always_update=True)

    def _rows(self, width: int) -> list[tuple[str, str]]:
        v = self.view
        rows = [(render.LINK_HEADER[:width], "header")]
        for link in v.links:
            row, state = render.link_row(link, v.now, v.stale_after)
            rows.append((row[:width], state))
            if state == "down" and link.reason:
                rows.append((("  " + link.reason)[:width], "down"))
        if v.links:
            rows += [("", "up"), (render.LINK_DETAIL_HEADER[:width], "header")]
            rows += [(render.link_detail(link, width), "wait") for link in v.links]
        return rows

    def lines(self, width: int) -> list[str]:
        return [r for r, _ in self._rows(width)]

    def render(self) -> Text:
        text = Text(no_wrap=True, overflow="crop")
        for i, (row, state) in enumerate(self._rows(self._width())):
            if i:
                text.append("\n")
            text.append(row, style=self.get_component_rich_style(f"link--{state}", partial=True))
        return text


class StatusBar(Static):
    """Top line: what is shown and whether a session is being recorded. Plain text (no
    markup): it shows paths and error messages, which may contain brackets."""

    def __init__(self, text: str = "", **kwargs) -> None:
        super().__init__(text, markup=False, **kwargs)
