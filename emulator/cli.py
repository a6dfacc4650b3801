"""``arva-emulate``: stream a scene's receiver sentences to a port.

``arva-emulate --scene S --port - --frames N --speed 0`` prints exactly the normative
sentences on stdout and nothing else; every log line goes to stderr.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import time
from collections.abc import Sequence

from firmware_proto.errors import InputError, LinkError
from firmware_proto.sentences import encode_epochs

from . import __version__
from .receiver import Receiver
from .scene import default_scene, load_scene

log = logging.getLogger("arva-emulate")

#: Epochs computed per batch when running as fast as possible (--speed 0).
FAST_BATCH = 4096


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="arva-emulate",
        description="Emulate an ARVA receiver: stream $PARVA sentences for a scene to a port.",
    )
    p.add_argument("--scene", metavar="FILE", help="scene TOML file (default: the embedded paper case study)")
    p.add_argument(
        "--port",
        default="-",
        metavar="PORT",
        help="'-' for stdout (default), a device path or a pyserial URL",
    )
    p.add_argument("--frames", type=_non_negative_int, metavar="N", help="stop after N epochs (default: run forever)")
    p.add_argument(
        "--speed",
        type=_speed,
        default=1.0,
        metavar="X",
        help="run X times real time; 0 = as fast as possible (default 1)",
    )
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


class _Output:
    """Where the sentences go: stdout, or a device/URL opened with pyserial."""

    def __init__(self, port: str) -> None:
        self.port = port
        self._serial = None
        if port == "-":
            self._write = sys.stdout.buffer.write
            self._flush = sys.stdout.buffer.flush
        else:
            import serial  # pyserial; imported only when a real port is asked for

            try:
                self._serial = serial.serial_for_url(port, baudrate=115200, write_timeout=0)
            except (serial.SerialException, ValueError, OSError) as exc:
                raise LinkError(f"port {port}: {exc}") from None
            self._write = self._serial.write
            self._flush = lambda: None

    def write(self, data: bytes) -> None:
        self._write(data)
        self._flush()

    def close(self) -> None:
        if self._serial is not None:
            self._serial.close()


def run(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene) if args.scene else default_scene()
    receiver = Receiver(scene)
    out = _Output(args.port)
    log.info("scene %s: %d transmitters, %d channels", scene.source, len(scene.transmitters), receiver.channels)
    remaining = args.frames
    period = 0.0 if args.speed == 0 else 1.0 / (scene.rate_hz * args.speed)
    start = time.monotonic()
    try:
        while remaining is None or remaining > 0:
            count = FAST_BATCH if period == 0 else 1
            if remaining is not None:
                count = min(count, remaining)
            if period:
                # Absolute deadlines: epoch k is due at start + k * period, so sleep
                # error never accumulates.
                delay = start + receiver.next_k * period - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            batch = receiver.next_batch(count)
            ep = batch.epochs
            out.write(encode_epochs(batch.k0, ep.ids, ep.d, ep.delta, ep.field))
            if remaining is not None:
                remaining -= count
    finally:
        out.close()
    log.info("%d epochs sent", receiver.next_k)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * args.verbose, stream=sys.stderr, format="arva-emulate: %(message)s"
    )
    try:
        return run(args)
    except (InputError, LinkError) as exc:
        print(f"arva-emulate: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, like any Unix filter, and
        # keep the interpreter's final flush of stdout from complaining.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
