"""``arva-emulate --capture DIR``: a copy of every byte a stream hands its device port.

:class:`CapturePort` sits directly on the device port (pty, serial, stdout ...), below
the link faults, so ``DIR/<stream>.bytes`` holds exactly what was offered to the device
after every fault (lost bytes absent, corrupted bytes corrupted, nothing during an
unplug); only what a full pty buffer then drops is not marked. Writes are unbuffered: a
test harness may read the file while the emulator runs, or after it was killed.
"""

from __future__ import annotations

from pathlib import Path

from emulator.output.ports import Port, PortWrapper


class CapturePort(PortWrapper):
    """Writes through to ``inner`` and appends the same bytes to ``path``."""

    def __init__(self, inner: Port, path: Path) -> None:
        super().__init__(inner)
        self._file = open(path, "ab", buffering=0)

    def write(self, data: bytes) -> int:
        if not self._file.closed:
            self._file.write(data)
        return self._account(len(data), self.inner.write(data))

    @property
    def bytes_dropped(self) -> int:  # type: ignore[override]
        return self.inner.bytes_dropped

    @bytes_dropped.setter
    def bytes_dropped(self, value: int) -> None:
        pass  # the device port counts its own drops

    def close(self, *args, **kwargs) -> None:
        super().close(*args, **kwargs)
        self.close_file()

    def close_file(self) -> None:
        """Stop capturing (the device port stays open)."""
        self._file.close()

