"""Wiring of the step clock and the control channel into ``arva-emulate`` (BRIEF 9).

``arva-emulate`` adds this module's options (:func:`add_arguments`) and, when
``--control`` is given, wraps its ports for ``--capture`` (:class:`CapturePort`) and
starts the socket server (:func:`start_server`) around its pipeline and scheduler;
requests are served by :class:`~emulator.control.controller.Controller`. Under the step
clock nothing else runs: the control thread steps.
"""

from __future__ import annotations

import argparse
import threading
from collections.abc import Callable
from pathlib import Path

from firmware_proto.errors import InputError

from emulator.output.ports import Port, PortWrapper, file_name
from emulator.output.scheduler import EpochScheduler
from emulator.pipeline import Pipeline

from emulator.control.controller import CLOCKS, Controller
from emulator.control.server import ControlAddress, ControlServer, check_host, control_address


def _address(text: str) -> ControlAddress:
    try:
        return control_address(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("hardware-in-the-loop testing (docs/hil_testing.md)")
    g.add_argument("--clock", choices=CLOCKS, default="real",
                   help="real: epochs at their times (--speed); step: nothing is emitted until a "
                   "control 'step' request asks (needs --control). Default real")
    g.add_argument("--control", type=_address, metavar="ADDRESS",
                   help="serve the JSON-lines control channel on unix:PATH (mode 0600) or tcp:HOST:PORT "
                   "(loopback only; port 0 picks one); announced as 'control ADDRESS'")
    g.add_argument("--capture", type=Path, metavar="DIR",
                   help="with --control: append every byte sent on each stream to DIR/<stream>.bytes "
                   "(test artefacts)")
    g.add_argument("--control-any-host", action="store_true",
                   help="allow a non-loopback HOST in --control tcp:HOST:PORT "
                   "(anyone who can reach it controls the emulator)")


def wanted(args: argparse.Namespace) -> bool:
    """True if the command line asks for a control session; InputError if it is incomplete."""
    if args.clock == "step" and args.control is None:
        raise InputError("--clock step: nothing would ever be emitted without --control ADDRESS to send 'step'")
    if args.control_any_host and args.control is None:
        raise InputError("--control-any-host: given without --control")
    if args.control is not None:
        check_host(args.control, args.control_any_host)  # before any port is opened
    if args.capture is not None:
        if args.control is None:
            raise InputError("--capture: given without --control")
        if not args.capture.is_dir():
            raise InputError(f"--capture {args.capture}: not a directory")
    return args.control is not None


class CapturePort(PortWrapper):
    """``--capture``: writes through to ``inner`` and appends the same bytes to ``path``.

    It sits directly on the device port (pty, serial, stdout ...), below the link faults,
    so the file holds exactly what was offered to the device after every fault (lost
    bytes absent, corrupted bytes corrupted, nothing during an unplug); only what a full
    pty buffer then drops is not marked. Writes are unbuffered: a test harness may read
    the file while the emulator runs, or after it was killed.
    """

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
        self._file.close()


def capture_ports(args: argparse.Namespace, ports: dict[str, Port]) -> dict[str, Port]:
    """``--capture DIR``: each device port wrapped so that what it is offered is also
    appended to ``DIR/<stream>.bytes`` (bound below any link faults: what the device was
    offered); closing a wrapper closes its device port, then its file."""
    if args.capture is None:
        return ports
    return {label: CapturePort(port, args.capture / (file_name(label) + ".bytes")) for label, port in ports.items()}


def start_server(args: argparse.Namespace, pipe: Pipeline, scheduler: EpochScheduler, stop: threading.Event,
                 announce: Callable[[str], None]) -> ControlServer:
    """Serve this run's control channel (a ``quit`` sets ``stop``), then announce
    ``control ADDRESS``: the channel accepts from then on."""
    controller = Controller(scheduler, pipe, args.clock)
    server = ControlServer(args.control, controller.handle, stop.set, any_host=args.control_any_host)
    announce(f"control {server.start()}")
    return server
