"""``arva-bench cat SOURCE``: decode a receiver stream, one JSON object per epoch on stdout.

SOURCE, the stop conditions and the exit statuses are those of the sub-command's
description (:func:`register`). Each epoch, in stream order, is printed and flushed as::

    {"seq": 12, "complete": true, "slots": [[1, 1905, 21], [-1, -1, -1]]}

with ``null`` for a slot that never arrived intact, plus ``"field": [[hx, hy, hz] | null,
...]`` when ``$PARVH`` research sentences came with it. At the end of the input the
decoder is flushed and one line of counters goes to stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import signal
import stat
import sys
import time

from emulator.cli_types import baud_rate, positive_int, positive_seconds
from firmware_proto.decoder import Decoder
from firmware_proto.errors import LinkError
from firmware_proto.events import Epoch

from .transport import open_device

#: Silence after which an epoch held for its last ``$PARVH`` is released (seconds).
IDLE_SECONDS = 0.1
CHUNK = 65536


class FileSource:
    """A regular file (read to EOF, never blocks); closed at the end when ``owned``."""

    def __init__(self, fd: int, owned: bool = True) -> None:
        self.fd = fd
        self.owned = owned

    def read(self) -> bytes | None:
        return os.read(self.fd, CHUNK)

    def close(self) -> None:
        if self.owned:
            os.close(self.fd)


class StreamSource(FileSource):
    """stdin or a FIFO: waits at most IDLE_SECONDS per read."""

    def read(self) -> bytes | None:
        ready, _, _ = select.select([self.fd], [], [], IDLE_SECONDS)
        return os.read(self.fd, CHUNK) if ready else None


class SerialSource:
    """A pyserial port: reads time out after IDLE_SECONDS; a port has no end of input."""

    def __init__(self, port) -> None:  # type: ignore[no-untyped-def]
        self.port = port

    def read(self) -> bytes | None:
        data = self.port.read(max(1, min(self.port.in_waiting, CHUNK)))
        return data or None

    def close(self) -> None:
        self.port.close()


def open_source(spec: str, baud: int = 115200) -> FileSource | SerialSource:
    """Open SOURCE, whose ``read()`` gives the next bytes, ``b""`` at end of input, None when
    nothing came for IDLE_SECONDS; raise :class:`LinkError` (``cat: SOURCE: reason``) when
    it cannot be."""
    if spec == "-":
        return StreamSource(sys.stdin.buffer.fileno(), owned=False)
    try:
        if "://" in spec or stat.S_ISCHR(mode := os.stat(spec).st_mode):
            return SerialSource(open_device(spec, baudrate=baud, timeout=IDLE_SECONDS))
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(21, "Is a directory")
        fd = os.open(spec, os.O_RDONLY | (os.O_NONBLOCK if stat.S_ISFIFO(mode) else 0))
        if stat.S_ISFIFO(mode):
            os.set_blocking(fd, True)
            return StreamSource(fd, owned=True)
        return FileSource(fd)
    except OSError as exc:  # includes serial.SerialException
        reason = exc.strerror or str(exc) or type(exc).__name__
        raise LinkError(f"cat: {spec}: {reason}") from None
    except ValueError as exc:  # pyserial: malformed URL or option
        raise LinkError(f"cat: {spec}: {exc}") from None


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "cat",
        help="decode $PARVA/$PARVH from a file, port or stdin to JSON lines",
        description=(
            "Decode the $PARVA/$PARVH stream of SOURCE (file, FIFO, - for stdin, serial device or "
            "pyserial URL) and print one JSON object per epoch on stdout, in stream order; a line "
            "of counters goes to stderr at the end. Exit status 0 at the end of the input (errors "
            "in the stream are counted, not fatal), 2 for bad arguments or a source that cannot be "
            "opened, 1 when a port fails mid-stream, 130 after Ctrl-C, 143 after SIGTERM."
        ),
    )
    p.add_argument("source", metavar="SOURCE", help="file path, device, pyserial URL, or - for stdin")
    p.add_argument("--baud", type=baud_rate, default=115200, help="baud rate for serial devices (default 115200)")
    p.add_argument("--epochs", type=positive_int, metavar="N", help="stop after N epochs")
    p.add_argument("--until-idle", type=positive_seconds, metavar="SECONDS",
                   help="stop when no byte arrives for SECONDS")
    p.add_argument("--expect-fields", action="store_true",
                   help="hold every epoch for the $PARVH of its last slot from the start (default: once one is seen)")

    def one_line_error(message: str) -> None:  # argparse's default prints the usage too
        p.exit(2, f"arva-bench: cat: {message} (see arva-bench cat --help)\n")

    p.error = one_line_error  # type: ignore[method-assign]


class _Done(Exception):
    """--epochs reached."""


class _PipeClosed(Exception):
    """stdout was closed by its reader (e.g. ``| head``)."""


class _Terminated(Exception):
    """SIGTERM arrived: stop as after Ctrl-C (flush, counters), exit status 143."""


def _on_sigterm(_signum, _frame) -> None:
    raise _Terminated


def run(args: argparse.Namespace) -> int:
    source = open_source(args.source, args.baud)
    dec = Decoder(expect_fields=args.expect_fields)
    printed = 0

    def emit(events: list) -> None:
        nonlocal printed
        for ev in events:
            if type(ev) is Epoch:
                try:
                    sys.stdout.write(json.dumps(ev.to_json()) + "\n")
                    sys.stdout.flush()
                except BrokenPipeError:
                    raise _PipeClosed from None
                printed += 1
                if args.epochs is not None and printed >= args.epochs:
                    raise _Done

    def finish() -> None:
        with contextlib.suppress(_Done):
            emit(dec.flush())

    status = 0
    last_data = time.monotonic()
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        while True:
            try:
                data = source.read()
            except OSError as exc:  # a port unplugged or failing mid-stream
                finish()
                reason = exc.strerror or str(exc) or type(exc).__name__
                print(f"arva-bench: cat: {args.source}: {reason}", file=sys.stderr)
                status = 1
                break
            if data is None:
                emit(dec.idle())
                if args.until_idle is not None and time.monotonic() - last_data >= args.until_idle:
                    finish()
                    break
                continue
            if not data:
                finish()
                break
            last_data = time.monotonic()
            emit(dec.feed(data))
    except _Done:
        pass
    except (KeyboardInterrupt, _Terminated) as exc:
        status = 130 if isinstance(exc, KeyboardInterrupt) else 143
        with contextlib.suppress(_PipeClosed):
            finish()
    except _PipeClosed:
        # Keep the interpreter's final flush of stdout from failing again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    finally:
        signal.signal(signal.SIGTERM, previous)
        source.close()
    counters = " ".join(f"{k}={v}" for k, v in dec.stats.as_dict().items())
    print(f"arva-bench: cat: {counters}", file=sys.stderr)
    return status
