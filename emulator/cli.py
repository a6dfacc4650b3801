"""``arva-emulate``: stream a scene's receiver (and ground-truth) sentences to ports.

``arva-emulate --scene S --port - --frames N --speed 0`` prints exactly the normative
sentences on stdout and nothing else; every log line, the live status and the final
summary go to stderr.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from collections.abc import Sequence

from firmware_proto.errors import InputError

from emulator import __version__
from emulator.cli_types import OneLineParser, baud_rate, existing_dir, non_negative_int, run_main, scene_file, seconds, speed
from emulator.output.ports import Port, PtyPort, SerialPort, StdoutPort
from emulator.scene.reader import default_scene, load_scene
from emulator.output.link_faults import FaultyPort
from emulator.output.scheduler import EpochScheduler, Route, SceneClock, status_printer, summary_line
from emulator.output.streams import scene_streams

log = logging.getLogger("arva-emulate")

_PARITIES = {"N": "N", "E": "E", "O": "O", "M": "M", "S": "S"}


def _stream_port(text: str) -> tuple[str, str]:
    label, sep, port = text.partition("=")
    if not sep or not label or not port:
        raise argparse.ArgumentTypeError(f"expected LABEL=PORT (e.g. gps:rx=pty), got {text!r}")
    return label, port


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="arva-emulate",
        description="Emulate an ARVA receiver: stream $PARVA sentences for a scene to a port.",
    )
    p.add_argument("--scene", type=scene_file, metavar="FILE", help="scene TOML file (default: the embedded paper case study)")
    p.add_argument(
        "--port",
        default="-",
        metavar="PORT",
        help="'-' for stdout (default), 'pty' to create pseudo-terminals (one per stream, "
        "each announced on stdout as '<stream> <path>'), a device path or a pyserial URL",
    )
    p.add_argument(
        "--stream",
        type=_stream_port,
        action="append",
        default=[],
        metavar="LABEL=PORT",
        help="send one stream (arva, arva:<id>, gps:rx, attitude:tx<id> ...) to its own port",
    )
    p.add_argument("--link", type=existing_dir, metavar="DIR", help="stable symlinks DIR/<stream> to the created ptys")
    p.add_argument("--frames", type=non_negative_int, metavar="N", help="stop after N epochs (default: run forever)")
    p.add_argument(
        "--speed",
        type=speed,
        default=1.0,
        metavar="X",
        help="run X times real time; 0 = as fast as possible (default 1)",
    )
    p.add_argument(
        "--delay",
        type=seconds,
        default=0.0,
        metavar="S",
        help="wait S seconds after announcing ptys before the first epoch (time for clients to open them)",
    )
    serial_opts = p.add_argument_group("serial device options (device paths and URLs)")
    serial_opts.add_argument("--baud", type=baud_rate, default=115200, help="baud rate (default 115200)")
    serial_opts.add_argument("--bytesize", type=int, choices=(5, 6, 7, 8), default=8)
    serial_opts.add_argument("--parity", choices=sorted(_PARITIES), default="N")
    serial_opts.add_argument("--stopbits", type=float, choices=(1, 1.5, 2), default=1)
    serial_opts.add_argument("--rtscts", action="store_true", help="hardware flow control")
    serial_opts.add_argument("--xonxoff", action="store_true", help="software flow control")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def _serial_options(args: argparse.Namespace, url: str) -> dict:
    opts = {
        "baudrate": args.baud,
        "bytesize": args.bytesize,
        "parity": args.parity,
        "stopbits": args.stopbits,
        "rtscts": args.rtscts,
        "xonxoff": args.xonxoff,
    }
    if "://" not in url:
        opts["exclusive"] = True  # a device another program holds is an error, not a fight
    return opts


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
        if port != "pty":
            users.setdefault(port, []).append(label)
    for port, names in users.items():
        if len(names) > 1:
            what = "stdout" if port == "-" else port
            raise InputError(
                f"port {port}: {len(names)} streams ({', '.join(names)}) cannot share {what}; "
                "use --port pty or --stream LABEL=PORT"
            )
    return ports


def open_port(label: str, spec: str, args: argparse.Namespace) -> Port:
    if spec == "-":
        return StdoutPort(label)
    if spec == "pty":
        link = None
        if args.link is not None:
            if not args.link.is_dir():
                raise InputError(f"--link {args.link}: not a directory")
            link = args.link / label.replace(":", "-")
        return PtyPort(label, link)
    return SerialPort(label, spec, _serial_options(args, spec))


def run(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene) if args.scene is not None else default_scene()
    streams = scene_streams(scene)
    specs = assign_ports([s.label for s in streams], args.port, args.stream)
    stop = threading.Event()
    _stop_on_signals(stop)
    scene_clock = SceneClock()
    # Pty announcements go to stdout, unless a stream's data does (--stream arva=-).
    announce = _announcer(sys.stderr if "-" in specs.values() else sys.stdout)
    routes: list[Route] = []
    try:
        for i, stream in enumerate(streams):
            port = open_port(stream.label, specs[stream.label], args)
            routes.append(Route(stream, port))
            if isinstance(port, PtyPort):
                # Announced before any data, flushed at once: a test harness or a human
                # reads the path from here and opens it (again after a simulated unplug).
                port.on_reconnect = announce
                announce(port)
            routes[-1].port = _with_link_faults(scene, port, i, args.speed, scene_clock)
        status = status_printer() if sys.stderr.isatty() and args.speed != 0 else None
        lf = scene.effects.link_faults
        scheduler = EpochScheduler(
            routes,
            args.speed,
            args.frames,
            status=status,
            stop_event=stop,
            scene_clock=scene_clock,
            # Outages are scheduled in scene time: render epoch by epoch so they land
            # on the right epochs even as fast as possible.
            fast_batch=1 if lf is not None and lf.disconnect_every_s > 0 else None,
        )
        try:
            scheduler.wait(args.delay)
            scheduler.run()
        finally:
            if status is not None:
                sys.stderr.write("\r\x1b[K")
        # Only after a normal end: an error is then the one line on stderr.
        print(f"arva-emulate: {summary_line(routes)}", file=sys.stderr, flush=True)
    finally:
        for r in routes:
            r.port.close()
    return 0


def _announcer(stream):
    def announce(port: Port) -> None:
        print(f"{port.label} {port.path}", file=stream, flush=True)

    return announce


def _with_link_faults(scene, port: Port, index: int, speed: float, clock: SceneClock) -> Port:
    """Wrap ``port`` in the scene's link faults if they apply to its stream."""
    fx = scene.effects
    if fx.link_faults is None or (fx.link_fault_streams and port.label not in fx.link_fault_streams):
        return port
    # Stalls and split gaps are real pauses in real time; as fast as possible they
    # cost nothing (the bytes still split and stall counters still count).
    sleep = time.sleep if speed > 0 else (lambda _s: None)
    return FaultyPort(port, fx.link_faults, scene.seed, stream=index, sleep=sleep, clock=clock)


def _stop_on_signals(stop: threading.Event) -> None:
    def handler(signum, frame):  # noqa: ARG001
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)


def main(argv: Sequence[str] | None = None) -> int:
    def parse() -> argparse.Namespace:
        args = parse_args(argv)
        logging.basicConfig(
            level=logging.WARNING - 10 * args.verbose, stream=sys.stderr, format="arva-emulate: %(message)s"
        )
        return args

    # SceneError bare: exactly FILE: key.path: reason, the form editors jump to.
    return run_main("arva-emulate", parse, run, bare_scene_errors=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
