"""Where emulated streams go: stdout, a pseudo-terminal, or a serial device / pyserial URL.

Every port behaves like a UART transmitter: :meth:`Port.write` never blocks and never
queues in memory; bytes the other side does not take are dropped and counted
(``bytes_dropped``), as a real UART loses what nobody reads. Only stdout blocks, as a
pipe should (``arva-emulate --port - | consumer`` must not lose data).
"""

from __future__ import annotations

import errno
import fcntl
import os
import sys
import termios
import tty
from pathlib import Path

from firmware_proto.errors import LinkError


class Port:
    """Base class of all ports. ``label`` names the stream (``arva``, ``gps:rx`` ...)."""

    #: Path announced to the user (``/dev/pts/3``), or None for ports that need none.
    path: str | None = None

    def __init__(self, label: str) -> None:
        self.label = label
        self.bytes_written = 0
        self.bytes_dropped = 0

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

    def _account(self, offered: int, accepted: int) -> int:
        self.bytes_written += accepted
        self.bytes_dropped += offered - accepted
        return accepted


class StdoutPort(Port):
    """Standard output. Blocking: a pipe applies back-pressure instead of losing data."""

    def __init__(self, label: str, stream=None) -> None:
        super().__init__(label)
        self._out = stream if stream is not None else sys.stdout.buffer

    def write(self, data: bytes) -> int:
        self._out.write(data)
        self._out.flush()
        return self._account(len(data), len(data))


def _write_nonblocking(fd: int, data: bytes) -> int:
    """os.write on a non-blocking fd; bytes that do not fit are not retried."""
    try:
        return os.write(fd, data)
    except BlockingIOError:
        return 0


class PtyPort(Port):
    """A pseudo-terminal pair made raw by us, behaving like a UART nobody may be reading.

    The slave side is kept open so the pty survives readers coming and going (no EIO,
    no hang-up); the master is written non-blocking and what does not fit the kernel
    buffer is dropped and counted. A pyserial reader flushes stale input when it opens
    the port, so a reader that reopens gets fresh epochs. ``link`` adds a stable
    symlink to the slave path, updated when the pty is re-created by a disconnect.
    """

    def __init__(self, label: str, link: Path | None = None) -> None:
        super().__init__(label)
        self.link = link
        self.disconnects = 0
        self._open()

    def _open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass through untouched
        tty.setraw(master)
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._master, self._slave = master, slave
        self.path = os.ttyname(slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.path)
            tmp.replace(self.link)  # atomic: a client never sees a missing link

    def write(self, data: bytes) -> int:
        if self._master < 0:  # disconnected: the bytes go nowhere
            return self._account(len(data), 0)
        return self._account(len(data), _write_nonblocking(self._master, data))

    def pending(self) -> int:
        """Bytes written but not yet read by the other side (in the kernel buffer)."""
        import array

        buf = array.array("i", [0])
        fcntl.ioctl(self._slave, termios.FIONREAD, buf)
        return buf[0]

    def disconnect(self) -> None:
        """Close both sides: a reader sees the device vanish (read error / EOF)."""
        if self._master >= 0:
            os.close(self._master)
            os.close(self._slave)
            self._master = self._slave = -1
            self.disconnects += 1

    def reconnect(self) -> None:
        """A new pty (new path, announced again); the ``link`` symlink follows it."""
        if self._master < 0:
            self._open()

    def close(self) -> None:
        self.disconnect()
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()


class SerialPort(Port):
    """A serial device path (``/dev/ttyUSB0``) or any pyserial URL, opened with pyserial.

    ``options`` are pyserial settings (``baudrate``, ``bytesize``, ``parity``,
    ``stopbits``, ``rtscts``, ``xonxoff``). Writes never block: on a POSIX device the
    file descriptor is written directly in non-blocking mode, because pyserial's
    ``write_timeout=0`` spins on EAGAIN; other URLs get a zero write timeout.
    """

    def __init__(self, label: str, url: str, options: dict | None = None) -> None:
        super().__init__(label)
        import serial  # imported only when a real port is asked for

        self.path = url
        try:
            self._serial = serial.serial_for_url(url, **(options or {}))
        except serial.SerialException as exc:
            raise LinkError(f"port {url}: {_reason(exc)}") from None
        except (ValueError, OSError) as exc:
            raise LinkError(f"port {url}: {exc}") from None
        self._fd = None
        try:
            fd = self._serial.fileno()
            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
            self._fd = fd
        except (AttributeError, NotImplementedError, OSError, ValueError, TypeError):
            self._serial.write_timeout = 0
        except Exception:  # pyserial raises its own types for URL handlers without fds
            self._serial.write_timeout = 0

    def write(self, data: bytes) -> int:
        if self._fd is not None:
            try:
                return self._account(len(data), _write_nonblocking(self._fd, data))
            except OSError as exc:
                raise LinkError(f"port {self.path}: write failed: {exc.strerror}") from None
        import serial

        try:
            n = self._serial.write(data)
        except serial.SerialTimeoutException:
            n = 0
        return self._account(len(data), n or 0)

    def close(self) -> None:
        self._serial.close()


def _reason(exc: Exception) -> str:
    """pyserial wraps OSErrors as '[Errno 2] could not open port X: [Errno 2] ...'."""
    err = getattr(exc, "errno", None)
    if err in (errno.ENOENT, errno.ENODEV):
        return "no such device"
    if err == errno.EACCES:
        return "permission denied (are you in the dialout group?)"
    if err == errno.EBUSY:
        return "device busy (another program has it open)"
    return str(exc)
