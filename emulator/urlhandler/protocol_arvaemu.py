"""``arvaemu://[SCENE][?receiver=ID&speed=X&frames=N&delay=S]``: an in-process receiver.

A pyserial port whose input is the ``$PARVA`` stream an emulated receiver would send,
with no pty and no thread: epochs are rendered lazily when the client reads, at the
scene's times from the moment the port opens (``speed`` times real time; 0: as fast as
read). The bytes come from the same :class:`~emulator.pipeline.Pipeline` as
``arva-emulate``'s, link faults included. docs/emulator.md, "In-process: arvaemu://",
gives the URL's forms and options.
"""

from __future__ import annotations

import argparse
import math
import time
import urllib.parse
from dataclasses import dataclass

from serial.serialutil import SerialBase, SerialException, Timeout

from firmware_proto.errors import InputError

from emulator.cli_types import non_negative_int, seconds, speed
from emulator.output.ports import BufferPort
from emulator.output.scheduler import Route
from emulator.pipeline import Pipeline, stream_layout
from emulator.scene.reader import default_scene, load_scene
from emulator.scene.types import Scene
from emulator.output.virtual_line import VirtualLine


class Serial(VirtualLine, SerialBase):
    """pyserial ``Serial`` for ``arvaemu://`` URLs (see the module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        self._pipeline: Pipeline | None = None
        self._route: Route | None = None
        self._buffer = bytearray()
        super().__init__(*args, **kwargs)

    # -- opening ----------------------------------------------------------------
    def open(self) -> None:
        self._may_open()
        u = parse_url(self._port)
        self._speed = u.speed
        label = stream_layout(u.scene)[u.index].label
        if self._pipeline is not None:
            self._pipeline.close_sources()
        self._pipeline = Pipeline(u.scene, [label])
        (self._route,) = self._pipeline.bind({label: BufferPort(label, self._buffer)}, self._speed)
        self._route.end_k = u.frames  # one stream: --frames' rule is its epoch count
        self._start = time.monotonic() + u.delay
        self.is_open = True

    # -- reading ----------------------------------------------------------------
    def _render_due(self, want: int) -> None:
        """Render the epochs due by now; at speed 0 (rendering follows the reader), whole
        epochs until ``want`` bytes are buffered."""
        route = self._route
        if self._speed == 0:
            per_epoch = 64 * max(1, route.stream.receiver.channels)
            due = route.next_k + max(1, math.ceil((want - len(self._buffer)) / per_epoch))
        else:
            elapsed = time.monotonic() - self._start
            due = math.floor(elapsed * route.stream.rate_hz * self._speed) + 1 if elapsed >= 0 else 0
        if route.end_k is not None:
            due = min(due, route.end_k)
        # Written through the pipeline's route: link faults apply, bytes land in _buffer.
        route.send(due - route.next_k, self._pipeline.clock)

    def _next_due_in(self) -> float:
        """Seconds until the next epoch is due (inf when the stream has ended)."""
        route = self._route
        if route.done:
            return math.inf
        if self._speed == 0:
            return 0.0
        t = self._start + route.next_k / (route.stream.rate_hz * self._speed)
        return max(0.0, t - time.monotonic())

    @property
    def in_waiting(self) -> int:
        self._require_open()
        if self._speed != 0:
            self._render_due(0)
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        self._require_open()
        timeout = Timeout(self._timeout)
        while len(self._buffer) < size:
            self._render_due(size)
            wait = self._next_due_in()
            if len(self._buffer) >= size or wait == math.inf or timeout.expired():  # expired: also timeout 0
                break
            time.sleep(wait if timeout.is_infinite else min(wait, timeout.time_left()))
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def reset_input_buffer(self) -> None:
        self._require_open()
        self._render_due(0)  # due epochs are produced (and lost), as on a real line
        self._buffer.clear()

    # -- writing and the rest ----------------------------------------------------
    def write(self, data) -> int:
        self._require_open()
        return len(data)

    def close(self) -> None:
        self.is_open = False
        self._buffer.clear()
        if self._pipeline is not None:
            self._pipeline.close_sources()
            self._pipeline = None
        super().close()


@dataclass(frozen=True)
class ArvaemuUrl:
    """What an ``arvaemu://`` URL asks for: the scene, the receiver's index in it, the
    speed (times real time, 0: as fast as read), the epoch count (None: endless) and the
    delay before the first epoch (s)."""

    scene: Scene
    index: int
    speed: float
    frames: int | None
    delay: float


def parse_url(url: str) -> ArvaemuUrl:
    """``url``'s scene and options, or :class:`SerialException` naming what is wrong."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "arvaemu":
        raise SerialException(f"expected arvaemu://[SCENE][?options], got {url!r}")
    options = urllib.parse.parse_qs(parts.query, keep_blank_values=True)
    known = {"receiver", "speed", "frames", "delay"}
    for key in options:
        if key not in known:
            raise SerialException(f"{url}: unknown option {key!r} (known: {', '.join(sorted(known))})")
    opt = {k: v[-1] for k, v in options.items()}
    path = parts.netloc + parts.path
    try:
        scene = default_scene() if path in ("", "default") else load_scene(path)
    except InputError as exc:
        raise SerialException(str(exc)) from None
    index = 0
    if "receiver" in opt:
        ids = [rx.id for rx in scene.receivers]
        if not opt["receiver"].isdigit() or int(opt["receiver"]) not in ids:
            raise SerialException(f"{url}: receiver={opt['receiver']}: no such receiver (ids: {ids})")
        index = ids.index(int(opt["receiver"]))
    return ArvaemuUrl(scene, index, _option(opt, "speed", speed, 1.0, url),
                      _option(opt, "frames", non_negative_int, None, url),
                      _option(opt, "delay", seconds, 0.0, url))


def _option(opt: dict, key: str, parse, default, url: str):
    """``key=`` by the rule of the command-line option of that name (emulator.cli_types:
    ``--speed``, ``--frames``, ``--delay``), ``default`` when not given."""
    if key not in opt:
        return default
    try:
        return parse(opt[key])
    except argparse.ArgumentTypeError as exc:
        raise SerialException(f"{url}: {key}={opt[key]}: {exc}") from None
