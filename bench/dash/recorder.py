"""Recording from the dashboard: the bytes the source threads already read, into a
session directory written exactly as ``arva-bench log`` writes one.

The source threads hand every read to :meth:`SessionRecorder.raw` (they never open a
device twice). Like :class:`bench.logger.DeviceLogger`, each read goes to
``SessionWriter.raw`` and the records a decoder derives from it to ``SessionWriter.record``
with ``mono``/``utc`` added; the recorder owns fresh decoders, so the session's records
derive from its own raw bytes alone (a sentence cut by the start of the recording is
flagged there, as in any log). Gaps and reconnects become session events. A disk error
stops the recording (``error`` says why); the dashboard keeps running.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from firmware_proto.errors import LinkError

from ..logger import DeviceSpec
from ..records import decoder_for
from ..session import SessionWriter


class SessionRecorder:
    def __init__(self, directory: str | Path, specs: list[DeviceSpec], manifest: dict) -> None:
        self.writer = SessionWriter(directory, manifest)
        self.directory = self.writer.dir
        self._decoders = {s.name: decoder_for(s.kind, s.format) for s in specs}
        self._stats = {s.name: {"reads": 0, "bytes": 0, "records": 0, "gaps": 0} for s in specs}
        self._lock = threading.Lock()  # reads of several devices arrive from their own threads
        self.closed = False
        self.error: str | None = None

    def raw(self, device: str, data: bytes, mono: float, utc: float) -> None:
        """One read of ``device`` (called from its source thread)."""
        with self._lock:
            if self.closed or self.error is not None:
                return
            try:
                self.writer.raw(device, data, mono, utc)
                decoder = self._decoders.get(device)
                records = decoder.feed(data) if decoder is not None else []
                self._store(device, records, mono, utc)
                st = self._stats.setdefault(device, {"reads": 0, "bytes": 0, "records": 0, "gaps": 0})
                st["reads"] += 1
                st["bytes"] += len(data)
            except LinkError as exc:
                self.error = str(exc)

    def _store(self, device: str, records: list[dict], mono: float, utc: float) -> None:
        for rec in records:
            self.writer.record(device, {"mono": round(mono, 6), "utc": round(utc, 6), **rec})
        if device in self._stats:
            self._stats[device]["records"] += len(records)

    def event(self, kind: str, device: str, **fields) -> None:
        """A session event (``gap``, ``reconnect``, ``unavailable``) of ``device``."""
        with self._lock:
            if self.closed or self.error is not None:
                return
            try:
                self.writer.event(kind, device=device, **fields)
                if kind == "gap" and device in self._stats:
                    self._stats[device]["gaps"] += 1
            except LinkError as exc:
                self.error = str(exc)

    def bytes_on_disk(self) -> int:
        return self.writer.bytes_on_disk()

    def close(self) -> dict:
        """Flush the decoders, close the session (manifest summary as ``arva-bench log``)."""
        with self._lock:
            if self.closed:
                return {}
            self.closed = True
            if self.error is None:
                mono, utc = time.monotonic(), time.time()
                try:
                    for name, decoder in self._decoders.items():
                        self._store(name, decoder.flush(), mono, utc)
                except LinkError as exc:
                    self.error = str(exc)
            summary = {
                name: {**st, "decoder": self._decoders[name].stats() if name in self._decoders else {}}
                for name, st in self._stats.items()
            }
            self.writer.close(devices=summary, stopped_by="disk error" if self.error else "user")
            return summary
