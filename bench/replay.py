"""``arva-bench replay DIR``: every logged device back on its own port, byte for byte,
with its recorded timing (``--speed X`` times real time; ``0`` as fast as possible).

Ports are opened by the emulator's own factory (emulator.output.factory), so a port
spec means what it means to ``arva-emulate``: ``--port pty`` (default) makes one
pseudo-terminal per device, announced on stdout as ``<device> <path>`` before any data;
``--device NAME=PORT`` sends one device elsewhere (a serial device, a URL, a regular
file or ``-``); ``--link DIR`` adds stable symlinks (DIR created if missing). ``rfc2217-server:HOST:PORT`` and ``tcp-server:HOST:PORT``
serve a device to network clients (loopback only unless ``--serve-any-host``; the URL to
open is announced like a pty; line 115200 8N1 until an RFC 2217 client sets its own). Reads are replayed in the order and at the times the logger
saw them (its monotonic clock), so interleaving across devices is preserved.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from pathlib import Path

from emulator.cli_types import output_dir, seconds, session_dir, speed
from emulator.output.factory import PortOptions, open_port
from emulator.output.net_ports import ServerPort, stderr_notifier
from emulator.output.ports import Port, PtyPort
from emulator.progress import progress
from firmware_proto.errors import InputError

from .ingest.pacer import load_reads, pace
from .session import load_manifest


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a session's devices on ptys with their timing", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", type=session_dir, metavar="DIR")
    p.add_argument("--speed", type=speed, default=1.0, metavar="X", help="X times real time; 0 = as fast as possible")
    p.add_argument("--port", default="pty", metavar="PORT", help="default port for every device (default pty)")
    p.add_argument("--device", action="append", default=[], metavar="NAME=PORT", help="one device to its own port")
    p.add_argument("--link", type=output_dir, metavar="DIR", help="stable symlinks DIR/<device> to the ptys (created if missing)")
    p.add_argument("--delay", type=seconds, default=0.0, metavar="S", help="wait S seconds after announcing the ptys")
    p.add_argument("--serve-any-host", action="store_true",
                   help="let rfc2217-server/tcp-server ports listen on non-loopback addresses")


def run(args: argparse.Namespace) -> int:
    directory = Path(args.session)
    manifest = load_manifest(directory)
    reads = load_reads(directory, manifest.devices)  # every line checked before any port opens
    names = list(reads)
    if not names:
        raise InputError(f"replay: {directory}: no device has logged anything")
    ports_for = {n: args.port for n in names}
    for item in args.device:
        name, sep, port = item.partition("=")
        if not sep or name not in ports_for:
            raise InputError(f"replay: --device {item}: expected NAME=PORT with NAME one of {', '.join(names)}")
        ports_for[name] = port
    if sum(1 for p in ports_for.values() if p == "-") > 1:
        raise InputError("replay: only one device can go to stdout (-)")
    if not any(log.reads for log in reads.values()):  # e.g. killed during its very first write: only a torn line
        raise InputError(f"replay: {directory}: no complete read in any device's raw log")
    ports: dict[str, Port] = {}
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with contextlib.ExitStack() as stack:  # the ports and the progress bar, closed before the summary line
        # Announcements go to stdout, unless a device's data does.
        announce_to = sys.stderr if "-" in ports_for.values() else sys.stdout
        options = PortOptions(link_dir=args.link, serve_any_host=args.serve_any_host,
                              notify=stderr_notifier("arva-bench: replay"))
        for name in names:
            ports[name] = stack.enter_context(open_port(name, ports_for[name], options))
            if isinstance(ports[name], (PtyPort, ServerPort)):
                print(f"{name} {ports[name].path}", file=announce_to, flush=True)
        if args.speed == 0:
            for port in ports.values():
                port.set_drain_wait(0.05)
        stop.wait(args.delay)
        # Every device's reads merged by the logger's clock, at their recorded pace.
        t0 = min(log.first.mono for log in reads.values() if log.first is not None)
        t_last = max(log.last.mono for log in reads.values() if log.last is not None)
        bar = stack.enter_context(progress("replay", total=t_last - t0, unit="s of session"))

        def deliver(name: str, read) -> None:
            ports[name].write(read.data)
            bar.update(completed=read.mono - t0)

        sent = pace(reads, deliver, args.speed, stop)
    dropped = sum(p.bytes_dropped for p in ports.values())
    written = sum(p.bytes_written for p in ports.values())
    print(f"arva-bench: replay: {sent} reads, {written} bytes written, {dropped} bytes dropped", file=sys.stderr)
    return 0
