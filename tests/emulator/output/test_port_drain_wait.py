"""The drain wait of a full port (emulator.output.ports._FdWriter, via set_drain_wait):
a pty we created that nobody has been seen reading waits at most PTY_FIRST_WAIT and is
then taken to be absent (later writes drop at once); a reader that keeps up is seen and
gets the whole wait, losing nothing however long it looks idle. Every read has a timeout."""

import os
import select
import threading
import time

import pytest

from emulator.output.ports import PTY_FIRST_WAIT, PtyPort

pytestmark = pytest.mark.pty

CHUNK = b"$PARVA,1,1834,45.0,1,0*00\r\n" * 4  # 108 bytes


def fill(port: PtyPort) -> int:
    """Write CHUNKs until one does not fit whole; bytes written."""
    total = 0
    while True:
        n = port.write(CHUNK)
        total += n
        if n < len(CHUNK):
            return total


@pytest.mark.slow
def test_an_unread_pty_waits_once_then_drops_at_once():
    port = PtyPort("arva")
    try:
        port.set_drain_wait(5.0)
        t0 = time.monotonic()
        fill(port)
        first = time.monotonic() - t0
        assert PTY_FIRST_WAIT <= first < 5.0  # the short wait, not the whole one
        t0 = time.monotonic()
        assert [port.write(CHUNK) for _ in range(50)] == [0] * 50
        assert time.monotonic() - t0 < PTY_FIRST_WAIT  # absent: no further waits
        assert port.bytes_dropped >= 50 * len(CHUNK)
    finally:
        port.disconnect()


@pytest.mark.slow
def test_a_reader_seen_draining_loses_nothing_through_a_long_pause():
    """Seen reading (a full buffer drained while the write waited), the reader then
    pauses 1 s, far longer than PTY_FIRST_WAIT, while the buffer is full again: nothing
    is dropped."""
    port = PtyPort("arva")
    fd = os.open(port.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    got = bytearray()

    def read_for(seconds: float, until: int | None = None) -> None:
        """Read for ``seconds``, or until ``until`` bytes are in (then any extra byte
        would be in ``got`` too: each read takes all there is)."""
        end = time.monotonic() + seconds
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        while time.monotonic() < end and (until is None or len(got) < until):
            if poller.poll(50):
                got.extend(os.read(fd, 65536))

    data = CHUNK * 1600  # 172,800 bytes: eight times the pty's buffer
    try:
        port.set_drain_wait(5.0)
        # The reader starts once the first write has filled the buffer: one reading all along
        # can let a single write take it all (seen under load), and then no wait sees it. The
        # first wait is longer than PTY_FIRST_WAIT so that a late start under load still counts.
        port._writer.first_wait = 2.0
        reader = threading.Timer(0.1, read_for, args=(5.0, len(data)))
        reader.start()
        assert port.write(data) == len(data)  # drained while waiting: the reader is seen
        reader.join(timeout=10)
        assert port._writer.reader_seen and bytes(got) == data
        port._writer.first_wait = PTY_FIRST_WAIT  # (what a reader not seen would get: 1 s is longer)
        later = threading.Timer(1.0, read_for, args=(5.0, 2 * len(data)))  # a 1 s pause, then reading again
        later.start()
        assert port.write(data) == len(data)
        later.join(timeout=10)
        read_for(0.3)  # nothing more comes
        assert bytes(got) == data * 2 and port.bytes_dropped == 0
    finally:
        os.close(fd)
        port.disconnect()


def test_a_re_created_pty_has_no_reader_seen():
    port = PtyPort("arva")
    try:
        port.set_drain_wait(5.0)
        port._writer.reader_seen = True  # as if the old pty had a reader
        port.disconnect()
        port.reconnect()
        assert (port._writer.reader_seen, port._writer.reader_absent) == (False, False)
    finally:
        port.disconnect()
