"""``arva-bench dash [SOURCE ...]``: a live terminal view of receivers, ground truth and links.

    arva-bench dash                                  # an emulated receiver, default scene
    arva-bench dash /dev/ttyUSB0 --gps /dev/ttyACM0 --attitude /dev/ttyUSB1 \\
                    --tx-pose 1=46.50012,8.00031,2499.2
    arva-bench dash campaigns/2026-01-15-a           # a logged session, with its timing

SOURCE is a receiver: a path or pyserial URL (``arvaemu://``, ``socket://``, ``usb://`` ...)
with an optional ``,role=rx<N>``; or a session directory, replayed in-process with its
recorded timing (``--speed``); or nothing: ``arvaemu://``, the emulator's default scene in
real time. ``--gps`` and ``--attitude`` (``,role=rx`` or ``,role=tx<ID>``), ``--tx-pose`` and
``--origin`` work as in ``arva-bench log``. For an ``arvaemu://`` source and no other ground
truth, the true poses come from the emulated scene.

Keys: r starts / stops recording a session into ``--record-dir`` (one new directory
per recording, named by its UTC start, written as ``arva-bench log`` writes), ? help,
q quit.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from emulator.cli_types import baud_rate, output_dir, positive_seconds, probe_creatable_dir, speed
from firmware_proto.errors import InputError

from ..ingest.pacer import load_reads
from ..log import add_truth_arguments, device_arg, device_specs
from ..preflight import check_sources
from ..session import load_manifest

DEFAULT_SOURCE = "arvaemu://"


def register(sub) -> None:
    p = sub.add_parser("dash", help="live terminal view of receivers, ground truth and links", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", nargs="*", type=device_arg("arva"), metavar="SOURCE[,role=rxN]",
                   help="a receiver (path or pyserial URL) or a session directory; default arvaemu://")
    add_truth_arguments(p, origin_help="ENU origin for GPS positions (default: the session's, else the first receiver fix)")
    p.add_argument("--baud", type=baud_rate, default=115200, help="baud rate for serial devices (default 115200)")
    p.add_argument("--speed", type=speed, default=1.0, metavar="X",
                   help="replay a session directory X times real time; 0 = as fast as possible (default 1)")
    p.add_argument("--stale", type=positive_seconds, default=3.0, metavar="S",
                   help="a device silent for S seconds is marked STALE and reopened (default 3)")
    p.add_argument("--record-dir", type=output_dir, default=Path("sessions"), metavar="DIR",
                   help="where r records sessions: DIR/<UTC start> (default ./sessions)")
    p.add_argument("--no-scene-truth", action="store_true",
                   help="do not take ground truth from an arvaemu:// source's scene")


#: Where a device that is not there yet may appear (plugged in later): the dashboard waits
#: for a missing path only below it; any other missing path is refused (a typo, or a
#: session directory that does not exist).
DEVICE_ROOT = "/dev/"


def check_path_may_appear(url: str) -> None:
    """:class:`InputError` for a plain path that does not exist outside :data:`DEVICE_ROOT`."""
    if "://" in url or url.startswith(DEVICE_ROOT) or os.path.lexists(url):
        return
    raise InputError(f"dash: {url}: no such file, device or session directory "
                     f"(a device not plugged in yet is waited for only under {DEVICE_ROOT})")  # fmt: skip


def build_config(args: argparse.Namespace, argv: list[str] | None = None):
    """The :class:`~bench.dash.app.DashConfig` of parsed arguments (InputError if unusable)."""
    from .app import DashConfig

    probe_creatable_dir(Path(args.record_dir), "dash: --record-dir")  # a recording must not fail in the TUI
    sources = list(args.source) or [(DEFAULT_SOURCE, "rx")]
    sessions = [url for url, _ in sources if os.path.isdir(url)]
    common = {"stale_after": args.stale, "record_dir": args.record_dir, "argv": list(sys.argv if argv is None else argv)}
    if sessions:
        if len(sources) > 1 or args.gps or args.attitude:
            raise InputError("dash: a session directory replays all its devices: give it as the only source")
        directory = Path(sessions[0])
        manifest = load_manifest(directory)
        logged = load_reads(directory, manifest.devices)  # a corrupt log: one line now, not a dead panel later
        specs = [dev for name, dev in manifest.devices.items() if name in logged]
        if not specs:
            raise InputError(f"dash: {directory}: no device has logged anything")
        origin = args.origin
        if origin is None and (o := manifest.origin) is not None:
            origin = [o.lat, o.lon, o.alt]
        tx_poses = list(args.tx_pose)
        known = {tx for tx, _ in tx_poses}
        for tx, pose in manifest.tx_poses.items():
            if tx not in known:
                attitude = [] if pose.heading is None else [pose.heading, pose.roll, pose.pitch]
                tx_poses.append((tx, [pose.lat, pose.lon, pose.alt, *attitude]))
        return DashConfig(specs=specs, replay=directory, replay_speed=args.speed, origin=origin,
                          tx_poses=tx_poses, scene_truth=False, **common)  # fmt: skip
    ns = argparse.Namespace(arva=sources, gps=args.gps, attitude=args.attitude, baud=args.baud)
    specs = device_specs(ns, command="dash")
    for spec in specs:
        check_path_may_appear(spec.url)
    scene_truth = not (args.no_scene_truth or args.gps or args.attitude or args.tx_pose)
    return DashConfig(specs=specs, origin=args.origin, tx_poses=list(args.tx_pose), scene_truth=scene_truth,
                      **common)  # fmt: skip


def run(args: argparse.Namespace) -> int:
    config = build_config(args)
    if config.replay is None:
        check_sources(config.specs, "dash")  # sources that can never work fail here, not in the TUI
    from .app import DashApp

    app = DashApp(config)
    app.run()
    if app.last_session is not None:
        print(f"arva-bench: dash: last recording: {app.last_session}", file=sys.stderr)
    return 0
