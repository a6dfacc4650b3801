"""What the source threads tell the dashboard. Threads only ever call ``app.post_message``
with one of these (textual's ``post_message`` is thread-safe); all state lives in the app.

``mono`` is ``time.monotonic()`` of the read that completed the record, the same clock the
app's ``clock`` defaults to, so "time since last data" is ``clock() - mono``.
"""

from __future__ import annotations

from dataclasses import dataclass

from textual.message import Message


@dataclass
class EpochReceived(Message):
    """One receiver epoch: ``slots[k-1]`` is ``(id, d, delta)`` or None (slot lost).

    ``count`` (here and in the other record messages) is the device's running number of
    such records: a source that thins a flood of records (more than the UI can draw)
    still lets the app compute the true rate. None counts this message as one."""

    device: str
    role: str
    seq: int
    slots: list[tuple[int, int, int] | None]
    mono: float
    complete: bool = True
    gap: int = 0
    count: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        self.slots = [None if s is None else tuple(s) for s in self.slots]


@dataclass
class FixReceived(Message):
    """A GPS record (the ``gps`` record dict of :mod:`bench.records`) for ``role``."""

    device: str
    role: str
    fix: dict
    mono: float
    count: int | None = None


@dataclass
class AttitudeReceived(Message):
    """A ``$PASHR`` attitude for ``role``: degrees and the ENU quaternion ``[w, x, y, z]``."""

    device: str
    role: str
    heading: float
    roll: float
    pitch: float
    q: tuple[float, ...]
    mono: float
    count: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        self.q = tuple(float(v) for v in self.q)


@dataclass
class TruthPose(Message):
    """A pose known without a sensor: the scene of an ``arvaemu://`` source (``via``
    ``"scene"``). ``position`` in the scene's ENU metres; ``q`` ``[w, x, y, z]``."""

    role: str
    position: tuple[float, float, float]
    q: tuple[float, ...] | None
    via: str
    mono: float

    def __post_init__(self) -> None:
        super().__post_init__()
        self.position = tuple(float(v) for v in self.position)
        self.q = None if self.q is None else tuple(float(v) for v in self.q)


@dataclass(frozen=True)
class LinkCounters:
    """Running counters of one device link (a snapshot; the thread keeps its own)."""

    reads: int = 0
    bytes: int = 0
    records: int = 0  #: epochs (arva), fixes + attitudes (gps, attitude)
    checksum_errors: int = 0
    errors: int = 0  #: every rejected sentence, checksum errors included
    seq_gaps: int = 0  #: arva only
    dropped_bytes: int = 0  #: bytes not part of any good sentence (junk + rejected)
    reconnects: int = 0
    last_data_mono: float | None = None


@dataclass
class LinkStatus(Message):
    """The state of one device link: ``state`` is ``connecting``, ``up``, ``down``
    (open failed or lost; retrying), or ``ended`` (a replayed session is over)."""

    device: str
    kind: str
    role: str
    url: str
    state: str
    counters: LinkCounters
    reason: str = ""
