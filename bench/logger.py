"""Writing what the ingest reads into a session: the :class:`SessionListener`.

A :class:`~bench.ingest.reader.Notifier` reads the devices and decodes each read once;
this listener appends every read to ``<device>.raw`` and its records (stamped by the
stamp rule, :mod:`bench.ingest.stamp`) to ``<device>.jsonl``, and turns link events into
session events (``unavailable``, ``gap``, ``reconnect``). ``arva-bench log`` and the
dashboard's recorder (:mod:`bench.dash.recorder`) both use it. A disk error (a full
disk) stops the writing, is kept in :attr:`SessionListener.error`, and is raised once as
:class:`LinkError` (the notifier reports it and drops the listener); everything written
before stays intact.
"""

from __future__ import annotations

from collections.abc import Callable

from firmware_proto.errors import LinkError

from .ingest.reader import Device, DeviceSpec, DeviceStats, LinkEvent, Listener, Read
from .records import is_positioned_fix
from .session import SessionWriter

__all__ = ["DeviceSpec", "DeviceStats", "SessionListener"]

#: Link events that become session events.
SESSION_EVENTS = ("unavailable", "gap", "reconnect")


def is_origin_fix(device: Device, record: dict) -> bool:
    """A valid GGA fix with a height from a receiver's GPS (the session's origin candidate)."""
    return device.spec.kind == "gps" and device.spec.role.startswith("rx") and is_positioned_fix(record)


class SessionListener(Listener):
    """Writes reads, records and link events into ``writer``; counts what it wrote.

    ``on_fix(lat, lon, alt_hae)``: called once, with the first receiver GPS fix (see
    :func:`is_origin_fix`), for a session without ``--origin``.
    """

    def __init__(self, writer: SessionWriter, on_fix: Callable[[float, float, float], None] | None = None) -> None:
        self.writer = writer
        self.on_fix = on_fix
        self.error: LinkError | None = None
        self.counts: dict[str, dict[str, int]] = {}

    def _count(self, name: str) -> dict[str, int]:
        return self.counts.setdefault(name, {"reads": 0, "bytes": 0, "records": 0, "gaps": 0})

    def on_read(self, device: Device, read: Read) -> None:
        if self.error is not None:
            return
        name = device.spec.name
        c = self._count(name)
        try:
            if read.data:
                self.writer.raw(name, read.data, read.mono, read.utc)
                c["reads"] += 1
                c["bytes"] += len(read.data)
            for s in read.records:
                self.writer.record(name, s.as_json())
                if self.on_fix is not None and is_origin_fix(device, s.record):
                    on_fix, self.on_fix, r = self.on_fix, None, s.record
                    on_fix(r["lat"], r["lon"], r["alt_hae"])
            c["records"] += len(read.records)
        except LinkError as exc:
            self.error = exc
            raise

    def on_link(self, device: Device, event: LinkEvent) -> None:
        if self.error is not None or event.kind not in SESSION_EVENTS:
            return
        fields = {"reason": event.reason} if event.reason else {}
        try:
            self.writer.event(event.kind, device=device.spec.name, **fields)
        except LinkError as exc:
            self.error = exc
            raise
        if event.kind == "gap":
            self._count(device.spec.name)["gaps"] += 1

    def summary(self, devices: list[Device]) -> dict:
        """Per device: reads, bytes, records, gaps written, and the decoder's counters (with
        the error records summed instead of written: see :mod:`bench.ingest.stamp`)."""
        return {d.spec.name: {**self._count(d.spec.name), "decoder": d.stamper.stats()} for d in devices}
