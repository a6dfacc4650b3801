"""``arva-bench log``: log receivers and ground-truth devices into a session directory.

    arva-bench log --arva /dev/ttyUSB0 --gps /dev/ttyACM0 --attitude /dev/ttyUSB1 \\
                   --tx-pose 1=46.50012,8.00031,2499.2 --out campaigns/2026-01-15-a

Every device argument is a path or pyserial URL; ``--gps`` and ``--attitude`` take
``,role=rx`` (default, the receiver) or ``,role=tx<ID>`` (a transmitter carrying the
sensor); ``--attitude URL,format=mavlink`` reads a drone autopilot's MAVLink attitude
instead of ``$PASHR`` (the ``mavlink`` extra). A transmitter may instead be given a
surveyed pose with ``--tx-pose``. Stops on Ctrl-C, SIGTERM or ``--duration``; prints a
summary; exit 0. A disk error stops the session with one line naming the file (exit 2);
everything before it is kept.
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import sys
import threading
import time

from emulator.cli_types import baud_rate, device_spec, origin, output_dir, positive_seconds, tx_pose, utf8_text
from firmware_proto.errors import InputError, LinkError

from . import __version__
from .log_status import LiveStatus
from .ingest.reader import SWITCH_INTERVAL, Device, Notifier
from .logger import DeviceSpec, SessionListener
from .records import FORMATS, decoder_for
from .preflight import check_sources
from .session import SessionWriter


def device_arg(kind: str):
    """argparse type for ``URL[,role=R][,format=F]`` of a device of ``kind`` (cli_types.device_spec)."""
    return device_spec(kind, FORMATS.get(kind))


def add_truth_arguments(p: argparse.ArgumentParser, origin_help: str) -> None:
    """The ground-truth options ``log`` and ``dash`` share: --gps, --attitude, --tx-pose, --origin."""
    p.add_argument("--gps", action="append", default=[], type=device_arg("gps"), metavar="URL[,role=R]",
                   help="a GPS (NMEA GGA/RMC/GLL; the export uses GGA); role rx (default) or tx<ID>")
    p.add_argument("--attitude", action="append", default=[], type=device_arg("attitude"),
                   metavar="URL[,role=R][,format=mavlink]",
                   help="an attitude unit ($PASHR; format=mavlink: an autopilot's MAVLink ATTITUDE_QUATERNION, "
                        "the mavlink extra); role rx (default) or tx<ID>")
    p.add_argument("--tx-pose", action="append", default=[], type=tx_pose, metavar="ID=LAT,LON,ALT[,H,R,P]",
                   help="a transmitter's surveyed pose (degrees, metres HAE; heading/roll/pitch in degrees)")
    p.add_argument("--origin", type=origin, metavar="LAT,LON[,ALT]", help=origin_help)


def register(sub) -> None:
    p = sub.add_parser("log", help="log devices into a session directory", description=__doc__)
    p.add_argument("--arva", action="append", default=[], type=device_arg("arva"), metavar="URL[,role=rxN]",
                   help="an ARVA receiver (repeatable)")
    add_truth_arguments(p, origin_help="geodetic origin of the session's ENU frame")
    p.add_argument("--out", required=True, type=output_dir, metavar="DIR", help="new session directory")
    p.add_argument("--baud", type=baud_rate, default=115200, help="baud rate for serial devices (default 115200)")
    p.add_argument("--duration", type=positive_seconds, metavar="S", help="stop after S seconds")
    p.add_argument("--note", type=utf8_text, default="", help="free text stored in the manifest (UTF-8)")


def device_specs(args: argparse.Namespace, command: str = "log") -> list[DeviceSpec]:
    """The devices of ``--arva`` / ``--gps`` / ``--attitude``; errors name ``command``."""
    specs: list[DeviceSpec] = []
    several = len(args.arva) > 1
    for i, (url, role) in enumerate(args.arva):
        role = role if role != "rx" or not several else f"rx{i + 1}"
        specs.append(DeviceSpec("arva" if not several else f"arva-{role}", "arva", url, role, args.baud))
    for kind in ("gps", "attitude"):
        for url, role, fmt in getattr(args, kind):
            if fmt is not None:
                decoder_for(kind, fmt)  # a missing extra is reported now, before a session exists
            specs.append(DeviceSpec(f"{kind}-{role}", kind, url, role, args.baud, fmt))
    names = [s.name for s in specs]
    for name in names:
        if names.count(name) > 1:
            raise InputError(f"{command}: two devices would both be {name!r}: give them different roles")
    if not any(s.kind == "arva" for s in specs):
        raise InputError(f"{command}: no receiver: give at least one --arva URL")
    return specs


def manifest(args: argparse.Namespace, specs: list[DeviceSpec], argv: list[str]) -> dict:
    out = {
        "devices": {s.name: s.manifest() for s in specs},
        "software": {"arva-bench": __version__, "python": platform.python_version()},
        # Argument bytes that are not UTF-8 kept as backslash escapes (JSON holds text, not bytes).
        "command": [os.fsencode(a).decode("utf-8", "backslashreplace") for a in argv],
        "note": args.note,
    }
    if args.origin:
        lat, lon, *alt = args.origin
        out["origin"] = {"lat": lat, "lon": lon, "alt": alt[0] if alt else 0.0}
    if args.tx_pose:
        keys = ("lat", "lon", "alt", "heading", "roll", "pitch")
        out["tx_poses"] = {str(tx): dict(zip(keys, values)) for tx, values in args.tx_pose}
    return out


#: Seconds a stop waits for the reads already taken to be written (a loaded machine can
#: leave seconds of backlog; losing them would be losing data).
STOP_TIMEOUT = 120.0


def run(args: argparse.Namespace) -> int:
    specs = device_specs(args)
    check_sources(specs, "log")  # a source that can never work is an error, not hours of nothing
    writer = SessionWriter(args.out, manifest(args, specs, sys.argv))
    stop = threading.Event()
    fatal: list[Exception] = []
    stopped_by = "user"

    def on_fatal(exc: Exception) -> None:
        fatal.append(exc)
        stop.set()

    def first_fix_origin(lat: float, lon: float, alt: float) -> None:
        # Without --origin, the first receiver GGA fix becomes the session's origin, written
        # into the manifest as soon as it arrives (export would pick the same fix; storing
        # it makes the session say where its ENU frame is).
        try:
            writer.update_manifest(origin=dict(lat=lat, lon=lon, alt=alt, source="first receiver fix"))
        except LinkError as exc:
            on_fatal(exc)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    devices = [Device(spec) for spec in specs]
    session = SessionListener(writer, on_fix=None if args.origin else first_fix_origin)
    notifier = Notifier(devices, [session], on_error=on_fatal, name="log", switch_interval=SWITCH_INTERVAL)
    notifier.start()
    t0 = time.monotonic()
    deadline = t0 + (float("inf") if args.duration is None else args.duration)
    status = LiveStatus(devices) if sys.stderr.isatty() else None
    live = status.start() if status is not None else None
    try:
        while not stop.wait(min(0.25, max(0.0, deadline - time.monotonic()))):
            if time.monotonic() >= deadline:
                stopped_by = "duration"
                break
            if status is not None:
                status.update(live, time.monotonic() - t0)
    finally:
        if live is not None:
            live.stop()
        notifier.stop(timeout=STOP_TIMEOUT)  # every read already taken is written first
        unfinished = notifier.thread.is_alive()
        summary = session.summary(devices)
        for dev in devices:
            if dev.cut_at_stop:
                summary[dev.spec.name]["cut_at_stop"] = dev.cut_at_stop
            if not dev.opens:
                summary[dev.spec.name]["never_opened"] = dev.reason or "not opened"
        writer.close(devices=summary, stopped_by="disk error" if fatal else stopped_by)
    late = f"the writer did not finish within {STOP_TIMEOUT:g} s; the last reads may be missing" if unfinished else ""
    never = [f"{dev.spec.name} never opened: {dev.reason or 'no attempt finished'}" for dev in devices if not dev.opens]
    # Exit 2 is one line: what went wrong, with what the reader needs to know folded in.
    if fatal:
        parts = [f"log: {fatal[0]}", *never, late, "the session was closed, everything before is kept"]
        raise LinkError("; ".join(p for p in parts if p))
    if not any(c["bytes"] for c in summary.values()):
        detail = f" ({'; '.join(never)})" if never else ""
        raise InputError(f"log: no device delivered a byte{detail}; {writer.dir} holds only the manifest and events")
    for dev in devices:
        c = summary[dev.spec.name]
        suppressed = c["decoder"].get("error_records_suppressed", 0)
        print(f"arva-bench: log: {dev.spec.name}: {c['reads']} reads, {c['bytes']} bytes, {c['records']} records, "
              f"{c['gaps']} gaps" + (f", {suppressed} error records summed (line noise)" if suppressed else ""),
              file=sys.stderr)
    for line in never + ([late] if late else []):
        print(f"arva-bench: log: {line}", file=sys.stderr)
    return 0
