"""``arva-emulate``: stream a scene's receiver (and ground-truth) sentences to ports.

``arva-emulate --scene S --port - --frames N --speed 0`` prints exactly the normative
sentences on stdout and nothing else; every log line, the live status and the final
summary go to stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from firmware_proto.errors import InputError

from emulator import __version__
from emulator.cli_types import OneLineParser, baud_rate, non_negative_int, output_dir, run_main, scene_file, seconds, speed
from emulator.control import runtime as control_runtime
from emulator.output.kworkers import raise_workers
from emulator.output.factory import PortOptions, open_port
from emulator.output.net_ports import LineSettings, ServerPort, is_ephemeral, stderr_notifier
from emulator.output.ports import Port, PtyPort
from emulator.scene.reader import default_scene, load_scene
from emulator.output.realtime import request_realtime
from emulator.output.scheduler import EpochScheduler, status_printer, summary_line
from emulator.pipeline import Pipeline
from emulator.receiver.profile import profile_table

def _stream_port(text: str) -> tuple[str, str]:
    label, sep, port = text.partition("=")
    if not sep or not label or not port:
        raise argparse.ArgumentTypeError(f"expected LABEL=PORT (e.g. gps:rx=pty), got {text!r}")
    return label, port


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="arva-emulate",
                      description="Emulate an ARVA receiver: stream $PARVA sentences for a scene to a port.")
    p.add_argument("--scene", type=scene_file, metavar="FILE", help="scene TOML file (default: the embedded paper case study)")
    p.add_argument("--port", default="-", metavar="PORT",
                   help="'-' for stdout (default), 'pty' to create pseudo-terminals (one per stream, "
                   "each announced on stdout as '<stream> <path>'), a device path or a pyserial URL, "
                   "'rfc2217-server:HOST:PORT' or 'tcp-server:HOST:PORT' (served to network clients; "
                   "port 0: any free port; the URL to open is announced like a pty), "
                   "or any other path: a file to write")
    p.add_argument("--stream", type=_stream_port, action="append", default=[], metavar="LABEL=PORT",
                   help="send one stream (arva, arva:<id>, gps:rx, attitude:tx<id> ...) to its own port "
                   "(as --port: -, pty, a device, a URL or a file)")
    p.add_argument("--serve-any-host", action="store_true",
                   help="let rfc2217-server/tcp-server ports listen on non-loopback addresses (a lab network)")
    p.add_argument("--link", type=output_dir, metavar="DIR", help="stable symlinks DIR/<stream> to the created ptys")
    p.add_argument("--frames", type=non_negative_int, metavar="N", help="stop after N epochs (default: run forever)")
    p.add_argument("--speed", type=speed, default=1.0, metavar="X",
                   help="run X times real time; 0 = as fast as possible (default 1)")
    p.add_argument("--realtime", action="store_true",
                   help="real-time epochs: ask for SCHED_FIFO and locked memory where permitted "
                   "(one stderr line if not)")
    p.add_argument("--realtime-workers", action="store_true",
                   help="with --realtime: also run the kernel's unbound workqueue workers (they carry a "
                   "pty's bytes to its reader) at SCHED_FIFO 1 for the run; host-wide, undone at exit "
                   "(one stderr line if not permitted)")
    p.add_argument("--timing-log", type=Path, default=None, metavar="FILE",
                   help="real-time runs: write each epoch's deadline and write() start/end (monotonic s) "
                   "to FILE at exit")
    p.add_argument("--delay", type=seconds, default=0.0, metavar="S",
                   help="wait S seconds after announcing ptys before the first epoch (time for clients to open them)")
    serial_opts = p.add_argument_group("serial device options (device paths and URLs)")
    serial_opts.add_argument("--baud", type=baud_rate, default=115200, help="baud rate (default 115200)")
    serial_opts.add_argument("--bytesize", type=int, choices=(5, 6, 7, 8), default=8)
    serial_opts.add_argument("--parity", choices=("E", "M", "N", "O", "S"), default="N")
    serial_opts.add_argument("--stopbits", type=float, choices=(1, 1.5, 2), default=1)
    serial_opts.add_argument("--rtscts", action="store_true", help="hardware flow control")
    serial_opts.add_argument("--xonxoff", action="store_true", help="software flow control")
    control_runtime.add_arguments(p)
    p.add_argument("--list-profiles", action="store_true", help="list the receiver profiles ([receiver] profile) and exit")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def assign_ports(labels: list[str], default: str, overrides: list[tuple[str, str]]) -> dict[str, str]:
    """Map every stream label to a port spec; raise InputError for impossible requests."""
    known = set(labels)
    ports = {label: default for label in labels}
    for label, port in overrides:
        if label not in known:
            raise InputError(f"--stream {label}={port}: no stream {label!r} in this scene (streams: {', '.join(labels)})")
        ports[label] = port
    users: dict[str, list[str]] = {}
    for label, port in ports.items():
        if port != "pty" and not is_ephemeral(port):  # ptys and port 0 servers: one each
            users.setdefault(port, []).append(label)
    for port, names in users.items():
        if len(names) > 1:
            what = "stdout" if port == "-" else port
            raise InputError(f"port {port}: {len(names)} streams ({', '.join(names)}) cannot share {what}; "
                             "use --port pty or --stream LABEL=PORT")
    return ports


def run(args: argparse.Namespace) -> int:
    if args.list_profiles:
        sys.stdout.write(profile_table())
        return 0
    if args.realtime_workers and not args.realtime:
        raise InputError("--realtime-workers: needs --realtime (the workers are raised only for a real-time run)")
    with_control = control_runtime.wanted(args)
    scene = load_scene(args.scene) if args.scene is not None else default_scene()
    pipe = Pipeline(scene)
    specs = assign_ports(pipe.labels, args.port, args.stream)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda _signum, _frame: stop.set())
    # Pty announcements go to stdout, unless a stream's data does (--stream arva=-).
    announce_to = sys.stderr if "-" in specs.values() else sys.stdout

    def announce(port: Port) -> None:
        _say(announce_to, f"{port.label} {port.path}")

    ports: dict[str, Port] = {}
    options = PortOptions(LineSettings(args.baud, args.bytesize, args.parity, args.stopbits), rtscts=args.rtscts,
                          xonxoff=args.xonxoff, link_dir=args.link, serve_any_host=args.serve_any_host,
                          notify=stderr_notifier("arva-emulate"))

    def close_ports() -> None:  # (``ports`` may be the capture wrappers by then)
        for port in ports.values():
            port.close()

    with contextlib.ExitStack() as opened:
        opened.callback(pipe.close_sources)
        opened.callback(close_ports)
        for label in pipe.labels:
            port = ports[label] = open_port(label, specs[label], options)
            if isinstance(port, (PtyPort, ServerPort)):
                # Announced before any data, flushed at once: a test harness or a human
                # reads the path from here and opens it (again after a simulated unplug).
                port.on_reconnect = announce
                announce(port)
        if with_control:  # --capture: the ports wrapped, so closed through the wrappers
            ports = control_runtime.capture_ports(args, ports)
        real = args.clock == "real"
        # Under the step clock a scene's link-fault stalls cost no wall time.
        routes = pipe.bind(ports, args.speed if real else 0)
        status = status_printer() if sys.stderr.isatty() and args.speed != 0 and real else None
        scheduler = EpochScheduler(routes, args.speed, args.frames, status=status, stop_event=stop,
                                   scene_clock=pipe.clock, fast_batch=pipe.fast_batch)
        timing = []
        if args.timing_log is not None:
            try:  # a bad path is an input error now, not after the run
                open(args.timing_log, "w").close()
            except OSError as exc:
                raise InputError(f"--timing-log: cannot write {args.timing_log}: {exc.strerror}") from None
            scheduler.on_write = lambda r, k, *times: timing.append((r.port.label, k, *times))
        with contextlib.ExitStack() as running:  # (closed whatever raises, before the summary)
            if with_control:
                running.callback(control_runtime.start_server(args, pipe, scheduler, stop,
                                                              lambda line: _say(announce_to, line)).close)
            if args.realtime and args.speed != 0 and real:
                if args.realtime_workers:  # before our own SCHED_FIFO, which the keeper would inherit
                    workers, refused = raise_workers()
                    if workers is not None:
                        running.callback(workers.close)
                    if refused:
                        _say(sys.stderr, refused)
                refused = request_realtime().message()
                if refused:
                    _say(sys.stderr, refused)
            if status is not None:
                running.callback(sys.stderr.write, "\r\x1b[K")
            scheduler.wait(args.delay)
            if real:
                scheduler.run()
            else:  # the step clock: the control thread steps; wait for quit or a signal
                while not stop.wait(0.2):
                    pass
        if args.timing_log is not None:
            _write_timing_log(args.timing_log, timing)
        # Only after a normal end: an error is then the one line on stderr.
        _say(sys.stderr, f"arva-emulate: {summary_line(routes)}")
    return 0


def _write_timing_log(path: Path, rows: list[tuple]) -> None:
    """``--timing-log``: one CSV line per epoch written in real time (monotonic seconds)."""
    with open(path, "w", encoding="ascii") as f:
        f.write("stream,epoch,deadline_s,write_start_s,write_end_s\n")
        for label, k, deadline, t0, t1 in rows:
            f.write(f"{label},{k},{deadline:.9f},{t0:.9f},{t1:.9f}\n")


def _say(stream, line: str) -> None:
    """One line in one write, flushed: the rfc2217 server's threads write lines to stderr
    too (``print`` writes text and newline apart, and one of theirs could land between)."""
    stream.write(line + "\n")
    stream.flush()


def main(argv: Sequence[str] | None = None) -> int:
    # SceneError bare: exactly FILE: key.path: reason, the form editors jump to.
    return run_main("arva-emulate", lambda: parse_args(argv), run, bare_scene_errors=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
