"""Recording from the dashboard: the reads the dashboard's reader already decoded, into a
session directory written exactly as ``arva-bench log`` writes one.

A :class:`SessionRecorder` is the log's :class:`~bench.logger.SessionListener`, attached
(through each :class:`~bench.dash.sources.DeviceFeed`) while recording. Devices are never
opened or decoded twice: a sentence cut by the start of the recording is decoded from the
bytes before it (its raw bytes start mid-sentence; a reader re-deriving records from the
raw log flags it). A disk error stops the recording (``error`` says why); the dashboard
keeps running.
"""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

from firmware_proto.errors import LinkError

from ..ingest.reader import Device, DeviceSpec, LinkEvent, Read
from ..logger import SessionListener
from ..session import SessionWriter


class SessionRecorder(SessionListener):
    def __init__(self, directory: str | Path, specs: list[DeviceSpec], manifest: dict) -> None:
        super().__init__(SessionWriter(directory, manifest))
        self.directory = self.writer.dir
        self._names = [s.name for s in specs]
        self._devices: dict[str, Device] = {}
        self._lock = threading.Lock()  # the reader thread writes; the UI thread closes
        self.closed = False

    def on_read(self, device: Device, read: Read) -> None:
        self._pass_on(device, super().on_read, read)

    def on_link(self, device: Device, event: LinkEvent) -> None:
        self._pass_on(device, super().on_link, event)

    def _pass_on(self, device: Device, handler, item) -> None:
        """The log's handler of ``item`` while recording; a disk error stays in ``error``
        and the dashboard goes on."""
        with self._lock:
            if self.closed:
                return
            self._devices[device.spec.name] = device
            with contextlib.suppress(LinkError):
                handler(device, item)

    def close(self) -> dict:
        """Close the session (manifest summary as ``arva-bench log`` writes it)."""
        with self._lock:
            if self.closed:
                return {}
            self.closed = True
            summary = {
                name: {**self._count(name), "decoder": self._devices[name].stamper.stats() if name in self._devices else {}}
                for name in dict.fromkeys(self._names + list(self.counts))
            }
            self.writer.close(devices=summary, stopped_by="disk error" if self.error is not None else "user")
            return summary
