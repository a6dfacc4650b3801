"""Where emulated streams go: stdout, a pseudo-terminal, a serial device / pyserial URL,
a regular file, or memory.

Every port behaves like a UART transmitter: :meth:`Port.write` never blocks and never
queues in memory; bytes the other side does not take are dropped and counted
(``bytes_dropped``), as a real UART loses what nobody reads. Only stdout blocks, as a
pipe should (``arva-emulate --port - | consumer`` must not lose data).
"""

from __future__ import annotations

import array
import errno
import fcntl
import os
import select
import stat
import sys
import termios
import time
import tty
from contextlib import AbstractContextManager
from pathlib import Path

import serial

from firmware_proto.errors import LinkError

#: The longest a full pty we created waits for a reader not yet seen reading (s): nobody
#: may be reading it, and a waiting step holds the control channel.
PTY_FIRST_WAIT = 0.3


def file_name(label: str) -> str:
    """A stream label as a file name (``gps:rx`` -> ``gps-rx``): the name of its ``--link``
    symlink and of its ``--capture`` file."""
    return label.replace(":", "-")


class Port(AbstractContextManager):
    """Base class of all ports. ``label`` names the stream (``arva``, ``gps:rx`` ...)."""

    #: Path announced to the user (``/dev/pts/3``), or None for ports that need none.
    path: str | None = None

    def __init__(self, label: str) -> None:
        self.label = label
        self.bytes_written = 0
        self.bytes_dropped = 0

    def set_drain_wait(self, seconds: float) -> None:
        """How long a full buffer may take to drain before bytes are dropped (0: never
        wait, the real-time behaviour). Ports without a buffer ignore it."""

    def write(self, data: bytes) -> int:
        """Send ``data`` without blocking; return the number of bytes accepted."""
        raise NotImplementedError

    def disconnect(self) -> None:
        """Simulate unplugging the device (link faults); :meth:`reconnect` undoes it."""
        raise LinkError(f"{self.label}: this port cannot be disconnected")

    def reconnect(self) -> None:
        raise LinkError(f"{self.label}: this port cannot be reconnected")

    def close(self) -> None:
        pass

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _account(self, offered: int, accepted: int) -> int:
        self.bytes_written += accepted
        self.bytes_dropped += offered - accepted
        return accepted


class PortWrapper(Port):
    """A port layered on a device port (link faults, a capture): unplug, replug, drain
    policy and close pass through to ``inner``, and so does anything else the device port
    offers (``pending()``, ``link`` ...). Subclasses write through and count."""

    def __init__(self, inner: Port) -> None:
        super().__init__(inner.label)
        self.inner = inner

    @property
    def path(self) -> str | None:  # type: ignore[override]
        return self.inner.path

    def set_drain_wait(self, seconds: float) -> None:
        self.inner.set_drain_wait(seconds)

    def disconnect(self) -> None:
        self.inner.disconnect()

    def reconnect(self) -> None:
        self.inner.reconnect()

    def close(self, *args, **kwargs) -> None:
        self.inner.close(*args, **kwargs)

    def __getattr__(self, name: str):
        if name.startswith("_") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)


class StdoutPort(Port):
    """Standard output. Blocking: a pipe applies back-pressure instead of losing data."""

    def __init__(self, label: str, stream=None) -> None:
        super().__init__(label)
        self._out = stream if stream is not None else sys.stdout.buffer

    def write(self, data: bytes) -> int:
        self._out.write(data)
        self._out.flush()
        return self._account(len(data), len(data))


class FilePort(Port):
    """A regular file, created or truncated: a stream recorded for later (``--stream
    gps=gps.nmea``). Writes block like stdout's: a disk does not drop bytes."""

    def __init__(self, label: str, path: str | Path) -> None:
        super().__init__(label)
        self.path = str(path)
        try:
            self._file = open(path, "wb")  # noqa: SIM115 (closed by close())
        except OSError as exc:
            raise LinkError(f"port {path}: cannot write: {exc.strerror or exc}") from None

    def write(self, data: bytes) -> int:
        try:
            self._file.write(data)
            self._file.flush()
        except OSError as exc:
            raise LinkError(f"port {self.path}: write failed: {exc.strerror or exc}") from None
        return self._account(len(data), len(data))

    def close(self) -> None:
        self._file.close()


def is_file_spec(spec: str) -> bool:
    """Whether a port spec names a regular file rather than a serial device: not a URL,
    not under /dev, and not an existing character device (``gps.nmea``, ``out/att.txt``)."""
    if "://" in spec or spec.startswith("/dev/"):
        return False
    try:
        return not stat.S_ISCHR(os.stat(spec).st_mode)
    except OSError:
        return True  # does not exist yet: a file to create


class BufferPort(Port):
    """Bytes kept in memory (``data``): the line of the in-process ``arvaemu://`` port.

    It cannot be unplugged, like stdout: link-fault outages on it are simulated (the
    bytes are dropped and counted, nothing is closed).
    """

    def __init__(self, label: str, data: bytearray | None = None) -> None:
        super().__init__(label)
        self.data = data if data is not None else bytearray()

    def write(self, data: bytes) -> int:
        self.data += data
        return self._account(len(data), len(data))


#: Bytes a full, unread pty still takes once its writer waits: the kernel moves written bytes
#: to the reader's side (the line discipline's 4096-byte read buffer) asynchronously.
KERNEL_MOVES = 4096


class _FdWriter:
    """Writes a non-blocking fd like a UART: what does not fit is dropped.

    With ``wait > 0`` a full buffer is given up to ``wait`` s *without progress* to
    drain, then the reader is taken to be absent and writes drop at once until the buffer
    takes bytes again; ``first_wait`` caps the wait for a reader not yet seen reading
    (docs/emulator.md, "Ports behave like a UART", says why). Progress, not a whole write
    fitting, is what counts: a present reader briefly stalled would otherwise stay
    "absent" for good when every write is larger than the buffer. A reader is seen when a
    full buffer takes bytes again, not from the pty's queue: the kernel moves written
    bytes to the reader's side asynchronously, so under load an unread pty looked read.
    """

    def __init__(self, wait: float = 0.0, first_wait: float | None = None) -> None:
        self.wait = wait
        self.first_wait = first_wait
        self.reset()

    def reset(self) -> None:
        """A new device (a re-created pty): no reader seen yet."""
        self.reader_absent = False
        self.reader_seen = self.first_wait is None

    def write(self, fd: int, data: bytes) -> int:
        done = _write_some(fd, data)
        if done > 0:
            if self.reader_absent:  # a full buffer took bytes again: someone read it
                self.reader_seen = True
            self.reader_absent = False
        if done == len(data) or self.wait <= 0 or self.reader_absent:
            return done
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        patience = self.wait if self.reader_seen else min(self.wait, self.first_wait)
        deadline = time.monotonic() + patience
        taken = 0  # bytes the full buffer took during this wait
        while done < len(data):
            left = deadline - time.monotonic()
            if left <= 0 or not poller.poll(left * 1000):
                self.reader_absent = True
                self.reader_seen = self.first_wait is None
                break
            wrote = _write_some(fd, data[done:])
            done += wrote
            taken += wrote
            # the reader took bytes: it is there, give it another `wait`; before it is seen,
            # not for what the kernel itself moves to the reader's side of an unread pty
            # (up to KERNEL_MOVES bytes, sometimes late: an unread pty once waited 0.3 + 5 s)
            if wrote > 0 and (self.reader_seen or taken > KERNEL_MOVES):
                self.reader_seen = True
                deadline = time.monotonic() + self.wait
        return done


def _write_some(fd: int, data: bytes) -> int:
    try:
        return os.write(fd, data)
    except BlockingIOError:
        return 0


class PtyPort(Port):
    """A raw pseudo-terminal pair behaving like a UART nobody may be reading (docs/emulator.md,
    "Ports behave like a UART"): the slave kept open, the master written non-blocking.
    ``link`` adds a stable symlink to the slave path, updated when a disconnect re-creates
    the pty; ``on_reconnect`` is then called with the port (to announce the new path).
    """

    def __init__(self, label: str, link: Path | None = None) -> None:
        super().__init__(label)
        self.link = link
        self.disconnects = 0
        self.on_reconnect = None
        self._writer = _FdWriter(first_wait=PTY_FIRST_WAIT)
        self._open()

    def set_drain_wait(self, seconds: float) -> None:
        self._writer.wait = seconds

    def _open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass through untouched
        tty.setraw(master)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._writer.reset()
        self.path = os.ttyname(slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.path)
            tmp.replace(self.link)  # atomic: a client never sees a missing link

    def write(self, data: bytes) -> int:
        if self._master < 0:  # disconnected: the bytes go nowhere
            return self._account(len(data), 0)
        return self._account(len(data), self._writer.write(self._master, data))

    def pending(self) -> int:
        """Bytes written but not yet read by the other side (in the kernel buffer)."""
        buf = array.array("i", [0])
        fcntl.ioctl(self._slave, termios.FIONREAD, buf)
        return buf[0]

    def disconnect(self) -> None:
        """Close both sides: a reader sees the device vanish (read error / EOF). The
        ``link`` symlink goes too, as udev's /dev/serial/by-id links do on unplug: the
        kernel soon hands the freed /dev/pts number to another program's pty, and a
        client reopening a dangling link must not end up reading that."""
        if self._master >= 0:
            os.close(self._master)
            os.close(self._slave)
            self._master = self._slave = -1
            self.disconnects += 1
            if self.link is not None and self.link.is_symlink():
                self.link.unlink()

    def reconnect(self) -> None:
        """A new pty (new path, announced again); the ``link`` symlink follows it."""
        if self._master < 0:
            self._open()
            if self.on_reconnect is not None:
                self.on_reconnect(self)

    def close(self, drain: float = 0.5) -> None:
        """Give a reader up to ``drain`` seconds to take what is buffered (closing the
        master discards it), then close and remove the symlink."""
        if self._master >= 0 and not self._writer.reader_absent:
            # The line buffer can look empty while the pty's flip buffer still holds
            # bytes on their way to it: require it empty twice, 20 ms apart.
            deadline = time.monotonic() + drain
            quiet = 0
            while quiet < 2 and time.monotonic() < deadline:
                quiet = quiet + 1 if self.pending() == 0 else 0
                time.sleep(0.02)
        self.disconnect()


class SerialPort(Port):
    """A serial device path (``/dev/ttyUSB0``) or any pyserial URL, opened with pyserial.

    ``options`` are pyserial settings (``baudrate``, ``bytesize``, ``parity``,
    ``stopbits``, ``rtscts``, ``xonxoff``). Writes never block: on a POSIX device the
    file descriptor is written directly in non-blocking mode, because pyserial's
    ``write_timeout=0`` spins on EAGAIN; other URLs get a zero write timeout.
    """

    def __init__(self, label: str, url: str, options: dict | None = None) -> None:
        super().__init__(label)
        self.path = url
        try:
            self._serial = serial.serial_for_url(url, **(options or {}))
        except serial.SerialException as exc:
            raise LinkError(f"port {url}: {_reason(exc)}") from None
        except (ValueError, OSError) as exc:
            raise LinkError(f"port {url}: {exc}") from None
        self._fd = None
        self._writer = _FdWriter()
        try:
            fd = self._serial.fileno()
            os.set_blocking(fd, False)
            self._fd = fd
        except (AttributeError, NotImplementedError, OSError, ValueError, serial.SerialException):
            self._serial.write_timeout = 0  # a URL handler without a file descriptor

    def write(self, data: bytes) -> int:
        if self._fd is not None:
            try:
                return self._account(len(data), self._writer.write(self._fd, data))
            except OSError as exc:
                raise LinkError(f"port {self.path}: write failed: {exc.strerror}") from None
        try:
            n = self._serial.write(data)
        except serial.SerialTimeoutException:
            n = 0
        return self._account(len(data), n or 0)

    def set_drain_wait(self, seconds: float) -> None:
        self._writer.wait = seconds

    def close(self) -> None:
        self._serial.close()


def _reason(exc: Exception) -> str:
    """pyserial wraps OSErrors as '[Errno 2] could not open port X: [Errno 2] ...'."""
    err = getattr(exc, "errno", None)
    if err in (errno.ENOENT, errno.ENODEV):
        return "no such device"
    if err == errno.EACCES:
        return "permission denied (are you in the dialout group?)"
    if err in (errno.EBUSY, errno.EAGAIN):  # EAGAIN: pyserial's exclusive flock failed
        return "device busy (another program has it open)"
    return str(exc)
