"""The command-line value types and the ``main()`` wrapper of every command.

One module, shared by ``arva-emulate``, every ``arva-bench`` sub-command and
``arva-sweep`` (in the spirit of python-can's ``can/cli.py``): each type is a callable
``str -> value`` for argparse's ``type=``, with a documented range (the table:
docs/reliability.md "Option value ranges"), that raises
:class:`argparse.ArgumentTypeError` with a one-line reason; argparse then prints
``PROG: error: argument --opt: REASON`` (one line, see :class:`OneLineParser`) and
exits with status 2.

Times are seconds, speeds are multiples of real time. The limits of the numeric options
are constants next to the options that use them (e.g. :data:`MAX_SECONDS`): large
enough for any real use, small enough that no accepted value overflows or hangs.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from firmware_proto.errors import InputError, LinkError, SceneError
from firmware_proto.sentences import MAX_ID

#: Baud rates a serial option may take: the slowest teletype to a 12 Mbaud FTDI bridge.
#: Outside them pyserial either refuses or overflows inside termios with a traceback.
BAUD_LIMITS = (50, 12_000_000)

#: The longest duration any option takes (a delay, a budget, a gap): one year, in s.
#: Longer ones are typos; beyond ~1e9 s ``time.sleep`` / ``Event.wait`` overflow.
MAX_SECONDS = 365.0 * 86400.0

#: Speeds (multiples of real time): 0 means as fast as possible; a positive speed below
#: MIN_SPEED would make one epoch last longer than :data:`MAX_SECONDS`.
MIN_SPEED = 1e-6
MAX_SPEED = 1e6

#: Seeds are what numpy's SeedSequence takes: non-negative, here below 2**63.
MAX_SEED = 2**63 - 1


def _fail(reason: str):
    raise argparse.ArgumentTypeError(reason)


def _named(fn: Callable, name: str) -> Callable:
    fn.__name__ = name  # argparse names the type in "invalid <name> value" messages
    return fn


def _parse_float(text: str) -> float:
    try:
        return float(text)
    except (ValueError, TypeError):
        _fail(f"expected a number, got {text!r}")


def _check_real(value: float, text: str, lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> float:
    if not math.isfinite(value):
        _fail(f"expected a finite number, got {text!r}")
    if lo is not None and (value < lo or (lo_open and value == lo)):
        _fail(f"must be {'>' if lo_open else '>='} {lo:g}, got {text}")
    if hi is not None and (value > hi or (hi_open and value == hi)):
        _fail(f"must be {'<' if hi_open else '<='} {hi:g}, got {text}")
    return value


def real(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False) -> Callable[[str], float]:
    """A finite float in [lo, hi]; ``lo_open`` / ``hi_open`` exclude the end."""

    def parse(text: str) -> float:
        return _check_real(_parse_float(text), text, lo, hi, lo_open, hi_open)

    return _named(parse, "number")


def speed_value(value: float, text: str | None = None) -> float:
    """The one speed rule (every command, replay's pacer, ``arvaemu://?speed=``): 0 (as
    fast as possible) or a finite number in [MIN_SPEED, MAX_SPEED]; else
    :class:`InputError` saying so (``text``: the value as the user wrote it)."""
    if value == 0:
        return 0.0
    if not math.isfinite(value) or not MIN_SPEED <= value <= MAX_SPEED:
        raise InputError(f"must be 0 (as fast as possible) or within {MIN_SPEED:g}..{MAX_SPEED:g}, got {text or value}")
    return float(value)


def speed(text: str) -> float:
    """``--speed``: :func:`speed_value` of the number written."""
    try:
        return speed_value(_parse_float(text), text)
    except InputError as exc:
        _fail(str(exc))


#: A duration in seconds: finite, in [0, MAX_SECONDS].
seconds = _named(real(0.0, MAX_SECONDS), "seconds")
#: A duration in seconds that must be > 0.
positive_seconds = _named(real(0.0, MAX_SECONDS, lo_open=True), "seconds")
#: A time shift in seconds, either sign.
signed_seconds = _named(real(-MAX_SECONDS, MAX_SECONDS), "seconds")


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """A whole number in [lo, hi] (decimal digits with an optional sign)."""

    def parse(text: str) -> int:
        t = text.strip()
        if not t.lstrip("+-").isdigit() or not t.isascii() or len(t) > 30:
            _fail(f"expected a whole number, got {text!r}")
        value = int(t)
        if lo is not None and value < lo:
            _fail(f"must be >= {lo}, got {value}")
        if hi is not None and value > hi:
            _fail(f"must be <= {hi}, got {value}")
        return value

    return _named(parse, "integer")


positive_int = _named(integer(1, 10**9), "integer")
non_negative_int = _named(integer(0, 10**12), "integer")
seed = _named(integer(0, MAX_SEED), "seed")


def baud_rate(text: str) -> int:
    """``--baud``: an integer in :data:`BAUD_LIMITS`."""
    value = integer()(text)
    lo, hi = BAUD_LIMITS
    if not lo <= value <= hi:
        _fail(f"must be within {lo}..{hi}, got {value}")
    return value


def real_list(n_min: int, n_max: int | None = None, lo: float | None = None, hi: float | None = None,
              *, lo_open: bool = False, what: str = "") -> Callable[[str], tuple[float, ...]]:
    """``n_min`` .. ``n_max`` comma-separated finite reals, each in [lo, hi]."""
    n_max = n_min if n_max is None else n_max
    prefix = f"{what}: " if what else ""

    def parse(text: str) -> tuple[float, ...]:
        parts = text.split(",")
        if not n_min <= len(parts) <= n_max:
            count = f"{n_min}" if n_min == n_max else f"{n_min}..{n_max}"
            _fail(f"{prefix}expected {count} comma-separated numbers, got {text!r}")
        try:
            return tuple(_check_real(_parse_float(p), p, lo, hi, lo_open, False) for p in parts)
        except argparse.ArgumentTypeError as exc:
            _fail(f"{prefix}{exc}")

    return _named(parse, "list of numbers")


def choice_list(names: Iterable[str], what: str = "name") -> Callable[[str], tuple[str, ...]]:
    """One or more comma-separated names out of ``names`` (no empty items, no repeats)."""
    allowed = tuple(names)

    def parse(text: str) -> tuple[str, ...]:
        items = tuple(text.split(","))
        for item in items:
            if item not in allowed:
                _fail(f"unknown {what} {item!r} (choose from {', '.join(allowed)})")
        if len(set(items)) != len(items):
            _fail(f"a {what} is repeated in {text!r}")
        return items

    return _named(parse, "list of names")


def utf8_text(text: str) -> str:
    """Free text (a note stored in a file): any UTF-8 text. A command line carries bytes;
    bytes that are not UTF-8 arrive as lone surrogates, which no UTF-8 file can store."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        offset = len(text[: exc.start].encode("utf-8", "surrogateescape"))
        _fail(f"not UTF-8 text (byte {offset})")
    return text


# --------------------------------------------------------------------------- geodetic values
#: Heights (m, above the WGS-84 ellipsoid) a pose may take: deeper than any mine, higher
#: than any aircraft carrying a bench.
ALT_LIMITS = (-12_000.0, 100_000.0)


#: (name, lo, hi, unit) of each value of a pose: latitude, longitude, altitude, then angles.
_POSE_RANGES = (("latitude", -90.0, 90.0, "degrees"), ("longitude", -180.0, 360.0, "degrees"),
                ("altitude", *ALT_LIMITS, "m")) + (("angles", -360.0, 360.0, "degrees"),) * 3


def _geodetic(values: tuple[float, ...], text: str, what: str) -> tuple[float, ...]:
    for (name, lo, hi, unit), value in zip(_POSE_RANGES, values):
        if not lo <= value <= hi:
            _fail(f"{what}: {name} must be within {lo:g}..{hi:g} {unit}, got {value:g}")
    return values


def origin(text: str) -> list[float]:
    """``LAT,LON[,ALT]``: degrees and metres above the ellipsoid."""
    return list(_geodetic(real_list(2, 3, what="--origin")(text), text, "--origin"))


def tx_pose(text: str) -> tuple[int, list[float]]:
    """``ID=LAT,LON,ALT[,HEADING,ROLL,PITCH]``: a transmitter's surveyed pose (degrees, m)."""
    tx, sep, rest = text.partition("=")
    if not sep or not tx.isascii() or not tx.isdigit() or len(tx) > 5 or int(tx) > MAX_ID:
        _fail(f"expected ID=lat,lon,alt[,heading,roll,pitch] with ID 0..{MAX_ID}, got {text!r}")
    what = f"--tx-pose {tx}"
    return int(tx), list(_geodetic(real_list(3, 6, what=what)(rest), rest, what))


def scheduler_address(text: str) -> str:
    """A dask scheduler address ``[SCHEME://]HOST:PORT`` (tcp, tls, ucx, ws, wss)."""
    scheme, sep, rest = text.rpartition("://")
    if sep and scheme not in ("tcp", "tls", "ucx", "ws", "wss"):
        _fail(f"unknown scheme {scheme!r} in {text!r} (tcp, tls, ucx, ws or wss)")
    host, colon, port = rest.rpartition(":")
    if not colon or not host or not host.isprintable() or not port.isascii() or not port.isdigit() or not 1 <= int(port) <= 65535:
        _fail(f"expected [SCHEME://]HOST:PORT (e.g. tcp://10.0.0.5:8786), got {text!r}")
    return text


# --------------------------------------------------------------------------- paths
#: The longest name of one path part and the longest whole path, in bytes (Linux's
#: NAME_MAX and PATH_MAX - 1): beyond them every system call fails with ENAMETOOLONG.
NAME_MAX = 255
PATH_MAX = 4095


def _short(part: bytes) -> str:
    return os.fsdecode(part[:16]) + "..."


def _path(text: str) -> Path:
    if not text:
        _fail("expected a path, got ''")
    if "\0" in text:
        _fail(f"a path cannot contain a NUL byte: {text!r}")
    raw = os.fsencode(text)
    if len(raw) > PATH_MAX:
        _fail(f"{_short(raw)}: a path longer than {PATH_MAX} bytes ({len(raw)})")
    for part in raw.split(b"/"):
        if len(part) > NAME_MAX:
            _fail(f"{_short(part)}: a path part longer than {NAME_MAX} bytes ({len(part)})")
    return Path(text)


def input_file(text: str) -> Path:
    """An existing regular file one can read."""
    path = _path(text)
    if not path.exists():
        _fail(f"{text}: no such file")
    if path.is_dir():
        _fail(f"{text}: is a directory, expected a file")
    if not path.is_file():  # a device, FIFO or socket: it may never end (/dev/zero) or block
        _fail(f"{text}: not a regular file")
    if not os.access(path, os.R_OK):
        _fail(f"{text}: not readable")
    return path


def session_dir(text: str) -> Path:
    """An existing directory (a session)."""
    path = _path(text)
    if not path.is_dir():
        _fail(f"{text}: not a directory")
    return path


def _writable_dir(path: Path) -> bool:
    return path.is_dir() and os.access(path, os.W_OK | os.X_OK)


def _creatable_file(text: str, suffixes: Sequence[str] | None) -> Path:
    path = _path(text)
    if suffixes and path.suffix not in suffixes:
        _fail(f"{text}: expected a {' or '.join(suffixes)} file")
    if path.is_dir():
        _fail(f"{text}: is a directory, expected a file")
    if path.exists() or path.is_symlink():
        if not path.is_file() or not os.access(path, os.W_OK):
            _fail(f"{text}: cannot be overwritten")
        return path
    parent = path.parent
    if not parent.is_dir():
        _fail(f"{text}: directory {parent} does not exist")
    if not _writable_dir(parent):
        _fail(f"{text}: directory {parent} is not writable")
    return path


def probe_creatable_dir(path: Path, what: str) -> None:
    """Prove that directory ``path`` exists and takes new entries, or can be created (a
    directory is made and removed in it or in its nearest existing ancestor): an
    InputError now rather than a failure later (catches what permission bits cannot, e.g.
    ``/proc/x`` as root). Nothing is left behind."""
    import tempfile

    base = _nearest_existing(path)
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".arva-probe-", dir=base))
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot create it in {base}: {exc.strerror or exc}") from None


def probe_writable(path: Path, what: str) -> None:
    """Create (then remove) ``path``, or append nothing to it: an InputError now rather
    than an OSError after hours of work (catches what permission bits cannot, e.g. /proc)."""
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot write: {exc.strerror or exc}") from None
    if not existed:
        path.unlink(missing_ok=True)


def output_file(suffixes: Sequence[str] | None = None) -> Callable[[str], Path]:
    """A file that can be created (or overwritten if it is a writable regular file)."""
    return _named(lambda text: _creatable_file(text, suffixes), "output file")


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def output_dir(text: str) -> Path:
    """An existing writable directory, or one that can be created (its nearest existing
    ancestor is a writable directory)."""
    path = _path(text)
    if path.exists():
        if not path.is_dir():
            _fail(f"{text}: exists and is not a directory")
        if not _writable_dir(path):
            _fail(f"{text}: directory is not writable")
        return path
    base = _nearest_existing(path)
    if not base.is_dir():
        _fail(f"{text}: {base} is not a directory")
    if not _writable_dir(base):
        _fail(f"{text}: cannot create it: {base} is not writable")
    return path


#: ``--scene``: an existing, readable scene file (``''`` is an error, not the default).
scene_file = input_file


# --------------------------------------------------------------------------- devices
def device_spec(kind: str, formats: Sequence[str] | None = None) -> Callable[[str], tuple]:
    """``URL[,role=R][,format=F]`` (options after the URL, in any order).

    Returns ``(url, role)``, or ``(url, role, format)`` for kinds that take a format
    (``formats`` not None). Roles: ``rx``, ``rx<ID>``, ``tx<ID>``.
    """

    def parse(text: str) -> tuple:
        url, role, fmt = text, "rx", None
        while True:
            head, sep, value = url.rpartition(",")
            key, eq, value = value.partition("=")
            if not sep or not eq or key not in ("role", "format"):
                break
            url = head
            if key == "role":
                role = value
            else:
                fmt = value
        if not (role == "rx" or (role.startswith(("rx", "tx")) and role[2:].isdigit() and role[2:].isascii())):
            _fail(f"{text!r}: role must be rx, rx<ID> or tx<ID>, got {role!r}")
        if fmt is not None and (formats is None or fmt not in formats):
            allowed = "no format option" if formats is None else "format " + " or ".join(formats)
            _fail(f"{text!r}: {kind} devices take {allowed}, got {fmt!r}")
        if not url:
            _fail(f"{text!r}: no device URL before the options")
        if "\0" in url:
            _fail(f"{text!r}: a device cannot contain a NUL byte")
        return (url, role) if formats is None else (url, role, fmt)

    return _named(parse, f"{kind} device")


# --------------------------------------------------------------------------- parser and main()
class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line: ``PROG: error: MESSAGE`` (exit 2).

    argparse's default prints the usage block first; ``--help`` still prints it in full.
    Sub-parsers made with :meth:`add_subparsers` inherit the class.
    """

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


def one_line(text: str) -> str:
    """``text`` on one line: inner line breaks become ``; ``."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip()) or str(text).strip()


def _os_error_line(exc: OSError) -> str:
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.filename is not None and getattr(exc, "filename2", None) is not None:
        return f"{exc.filename} -> {exc.filename2}: {reason}"  # symlink, rename
    if exc.filename is not None:
        return f"{exc.filename}: {reason}"
    return reason


def run_main(prog: str, parse: Callable[[], argparse.Namespace], run: Callable[[argparse.Namespace], int],
             *, bare_scene_errors: bool = False) -> int:
    """Parse, run, and map every expected failure to one stderr line and an exit status
    (docs/reliability.md "Guarantees"): argparse errors one line, 2 (``--help``: 0);
    :class:`InputError` (incl. a missing extra) and :class:`LinkError` ``PROG: MESSAGE``, 2
    (a :class:`SceneError` bare, ``FILE: key: reason``, with ``bare_scene_errors``); any
    other :class:`OSError`, also from an argument's type, ``PROG: PATH: REASON``, 2; a
    closed stdout (``| head``) quietly 0; Ctrl-C ``PROG: interrupted``, 130. Anything else
    is a bug and keeps its traceback. Logging goes to stderr as ``PROG: MESSAGE`` at
    WARNING less 10 per ``-v`` of the parsed ``verbose`` count.
    """
    try:
        args = parse()
        logging.basicConfig(level=logging.WARNING - 10 * getattr(args, "verbose", 0), stream=sys.stderr,
                            format=f"{prog}: %(message)s")
        return int(run(args) or 0)
    except (InputError, LinkError) as exc:
        bare = bare_scene_errors and isinstance(exc, SceneError)
        print(one_line(exc) if bare else f"{prog}: {one_line(exc)}", file=sys.stderr, flush=True)
        return 2
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, like any Unix filter, and
        # keep the interpreter's final flush of stdout from complaining.
        with contextlib.suppress(OSError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        return 0
    except OSError as exc:
        print(f"{prog}: {one_line(_os_error_line(exc))}", file=sys.stderr, flush=True)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr, flush=True)
        return 130
