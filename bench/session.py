"""Crash-safe session directories: every byte read, timestamped, append-only.

Layout (docs/bench.md, section 4): ``manifest.json`` (atomic rewrite), ``events.jsonl``,
``<device>.raw`` (one line per read: ``mono_s <TAB> utc_iso <TAB> base64(bytes)``) and
``<device>.jsonl`` (records derived from the raw bytes). Each line is written with one
``write`` and flushed at once (a SIGKILL loses nothing the kernel has); a background
thread fsyncs dirty files at least once a second (a power cut loses at most the last
second). ``mono_s`` is ``time.monotonic()`` of the logging process, for intervals;
``utc_iso`` (``2026-11-22T08:01:02.123456Z``) is wall time.

Readers never hold a whole file and tolerate a torn last line: :class:`RawLog` streams a
``.raw`` and checks every read's stamps against the session's clock (:class:`SessionClock`);
only regular files are read, lines and manifests have caps (``MAX_*``). What breaks a
rule or a cap is an :class:`InputError` of one line naming the file and line.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import errno
import datetime as _dt
import json
import math
import os
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeVar

import msgspec

from emulator.cli_types import BAUD_LIMITS
from emulator.files import open_regular, read_regular
from emulator.schema import Int, Number, SchemaError, Text, convert, join_key, type_name
from firmware_proto.errors import InputError, LinkError

from .ingest.stamp import Stamped
from .records import FORMATS, KINDS

MANIFEST = "manifest.json"
EVENTS = "events.jsonl"
T = TypeVar("T")
FORMAT = "arva-session"
FORMAT_VERSION = 2
#: Bytes of padding kept after the manifest's text (see SessionWriter._write_manifest).
MANIFEST_RESERVE = 8192


def utc_iso(t: float | None = None) -> str:
    """UTC wall time as ISO 8601 with microseconds and a ``Z``."""
    t = time.time() if t is None else t
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_utc(text: str) -> float:
    return _dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=_dt.timezone.utc).timestamp()


class _AppendFile:
    """One append-only file: whole lines, flushed per line, fsynced by the writer."""

    def __init__(self, path: Path) -> None:
        self._f = open(path, "ab", buffering=0)  # unbuffered: one write() per line
        self.lock = threading.Lock()
        self.dirty = False
        self.bytes = 0
        self.torn = False

    def write_line(self, line: bytes) -> None:
        """Append one whole line. A raw unbuffered write may take only part of it (a disk
        filling up): the rest is retried; if the disk then refuses, the file is left with
        a torn last line and refuses every later line, so a torn line is only ever the
        tail, which the readers tolerate."""
        with self.lock:
            if self.torn:
                raise OSError(errno.EIO, "an earlier line was cut short; nothing more is appended")
            view = memoryview(line)
            try:
                while view:
                    n = self._f.write(view)
                    if not n:
                        raise OSError(errno.ENOSPC, "short write: no space left on device")
                    view = view[n:]
                    self.dirty = True
            finally:
                self.bytes += len(line) - len(view)
                if 0 < len(view) < len(line):
                    self.torn = True

    def sync(self) -> None:
        with self.lock:
            if self.dirty:
                os.fsync(self._f.fileno())
                self.dirty = False

    def close(self) -> None:
        with self.lock:
            if not self._f.closed:
                os.fsync(self._f.fileno())
                self._f.close()


class SessionWriter(contextlib.AbstractContextManager):
    """Writes one session directory; safe to call from several reader threads.

    ``fsync_interval`` (s) bounds what a power cut can lose. A disk error (e.g. a full
    disk) raises :class:`LinkError` naming the file; everything written before it stays
    intact (the files are append-only and were flushed line by line).
    """

    def __init__(self, directory: str | Path, manifest: dict, fsync_interval: float = 1.0) -> None:
        self.dir = Path(directory)
        if self.dir.exists() and any(self.dir.iterdir()):
            raise InputError(f"{self.dir}: not empty; a session never overwrites another (choose a new --out)")
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{self.dir}: cannot create: {exc.strerror}") from None
        self.manifest = {"format": FORMAT, "version": FORMAT_VERSION, **manifest, "start_utc": utc_iso()}
        self._files: dict[str, _AppendFile] = {}
        self._files_lock = threading.Lock()
        self._manifest_lock = threading.Lock()
        self._write_manifest()
        self.event("start")
        self._stop = threading.Event()
        self._fsync_interval = fsync_interval
        self._syncer = threading.Thread(target=self._sync_loop, name="session-fsync", daemon=True)
        self._syncer.start()
        self.closed = False

    # -- files -------------------------------------------------------------------
    def _file(self, name: str) -> _AppendFile:
        with self._files_lock:
            f = self._files.get(name)
            if f is None:
                f = self._files[name] = _AppendFile(self.dir / name)
            return f

    def _append(self, name: str, line: bytes) -> None:
        try:
            self._file(name).write_line(line)
        except OSError as exc:
            raise LinkError(f"{self.dir / name}: write failed: {exc.strerror or exc}") from None

    def update_manifest(self, **fields) -> None:
        """Add ``fields`` to the manifest now (atomically: a crash leaves the old or the new)."""
        with self._manifest_lock:
            self.manifest.update(fields)
            try:
                self._write_manifest()
            except OSError as exc:
                raise LinkError(f"{self.dir / MANIFEST}: write failed: {exc.strerror or exc}") from None

    def _manifest_text(self) -> bytes:
        return json.dumps(self.manifest, indent=2, sort_keys=True).encode() + b"\n"

    def _write_manifest(self) -> None:
        """Atomic rewrite (a crash leaves the old manifest or the new one). The file is padded
        with spaces (JSON allows trailing white space) to at least :data:`MANIFEST_RESERVE`
        bytes beyond its text, so that when a full disk refuses the new file the final
        manifest can still be written over the blocks the old one already holds."""
        data = self._manifest_text() + b" " * MANIFEST_RESERVE + b"\n"
        tmp = self.dir / (MANIFEST + ".tmp")
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.dir / MANIFEST)
        except OSError:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        dir_fd = os.open(self.dir, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself survives a power cut
        finally:
            os.close(dir_fd)

    def _overwrite_manifest(self) -> None:
        """The last resort of a full disk: the manifest written in place, over the old one's
        blocks (no allocation), its text padded with spaces to the old length."""
        path = self.dir / MANIFEST
        text = self._manifest_text()
        size = path.stat().st_size
        if len(text) + 1 > size:
            raise OSError(errno.ENOSPC, "no room for the final manifest")
        fd = os.open(path, os.O_WRONLY)
        try:
            os.pwrite(fd, text + b" " * (size - len(text) - 1) + b"\n", 0)
            os.fsync(fd)
        finally:
            os.close(fd)

    # -- what callers write -------------------------------------------------------
    def raw(self, device: str, data: bytes, mono: float | None = None, utc: float | None = None) -> None:
        """Append one read of ``device``: the bytes exactly as they came."""
        mono = time.monotonic() if mono is None else mono
        line = b"%.6f\t%s\t%s\n" % (mono, utc_iso(utc).encode(), base64.b64encode(data))
        self._append(f"{device}.raw", line)

    def record(self, device: str, record: dict) -> None:
        """Append one decoded record of ``device`` (a JSON object)."""
        self._append(f"{device}.jsonl", json.dumps(record, separators=(",", ":")).encode() + b"\n")

    def event(self, kind: str, **fields) -> None:
        """Append a session event (start, stop, gap, reconnect, error ...)."""
        obj = {"utc": utc_iso(), "mono": round(time.monotonic(), 6), "event": kind, **fields}
        self._append(EVENTS, json.dumps(obj, separators=(",", ":")).encode() + b"\n")

    def bytes_on_disk(self) -> int:
        with self._files_lock:
            return sum(f.bytes for f in self._files.values())

    # -- lifetime ----------------------------------------------------------------
    def _sync_loop(self) -> None:
        while not self._stop.wait(self._fsync_interval / 2):
            self._each_file(_AppendFile.sync)  # an error is reported by the next write to that file

    def _each_file(self, action) -> None:
        """``action(file)`` on every open file; an OSError leaves the others to do."""
        with self._files_lock:
            files = list(self._files.values())
        for f in files:
            with contextlib.suppress(OSError):
                action(f)

    def __exit__(self, *_) -> None:
        self.close()

    def close(self, **summary) -> None:
        """Record the stop, fsync everything, and finish the manifest."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(LinkError):  # the disk is full: the manifest rewrite below may still fit
            self.event("stop", **summary)
        self._stop.set()
        self._syncer.join(timeout=5)
        self._each_file(_AppendFile.close)
        with self._manifest_lock:
            self.manifest["stop_utc"] = utc_iso()
            if summary:
                self.manifest["summary"] = summary
            try:
                self._write_manifest()
            except OSError:
                with contextlib.suppress(OSError):  # the previous manifest is still there, whole
                    self._overwrite_manifest()


# -- the manifest, typed ---------------------------------------------------------------
class DeviceSpec(msgspec.Struct, frozen=True):
    """A device to read, or one a session logged (its ``<name>.raw`` holds the reads):
    ``name`` in the session (``arva``, ``gps-rx``, ``attitude-tx1``), ``kind`` (arva, gps,
    attitude), ``role`` (``rx``, ``rx<id>`` or ``tx<id>``), ``format`` (None: the kind's
    default; ``mavlink`` for a MAVLink attitude source), ``baudrate`` (bit/s, 8N1: the
    port's setting and the stamp rule's byte time, :mod:`bench.ingest.stamp`)."""

    name: str
    kind: Literal[KINDS]
    url: str = ""
    role: Text(r"\A(rx|rx\d+|tx\d+)\Z", "rx, rx<ID> or tx<ID>") = "rx"
    baudrate: Int(*BAUD_LIMITS) = 115200
    format: str | None = None

    def manifest(self) -> dict:
        """The device's entry in the manifest (under its name; ``format`` only when given)."""
        return {k: v for k, v in msgspec.structs.asdict(self).items() if k != "name" and v is not None}


class GeoPose(msgspec.Struct, frozen=True):
    """A surveyed point (degrees, metres HAE) with an optional attitude (degrees)."""

    lat: Number(-90.0, 90.0, unit="")
    lon: Number(-180.0, 180.0, unit="")
    alt: Number(-1e5, 1e5, unit="")
    heading: Number(-360.0, 360.0, unit="") | None = None
    roll: Number(-180.0, 180.0, unit="") = 0.0
    pitch: Number(-90.0, 90.0, unit="") = 0.0


class _Origin(GeoPose, frozen=True):
    alt: Number(-1e5, 1e5, unit="") = 0.0


class _ManifestTable(msgspec.Struct, frozen=True):
    """What this program reads of a manifest (other keys, a note, the command, are kept)."""

    version: Int(1, 2**31)
    devices: dict[str, dict] = {}  # each a DeviceSpec, converted one by one to name it
    start_utc: str | None = None
    stop_utc: str | None = None
    origin: _Origin | None = None
    tx_poses: dict[str, dict] = {}  # each a GeoPose
    summary: dict | None = None


def _typed(value: object, type_: type[T], where: str) -> T:
    try:
        return convert(value, type_, "an object")
    except SchemaError as exc:
        raise ValueError(f"{join_key(where, exc.key)}: {exc.reason}") from None


@dataclass(frozen=True)
class Manifest:
    """``manifest.json`` of a session, validated. Format versions: 1 (records stamped with
    their read's time), 2 (records stamped by the stamp rule of :mod:`bench.ingest.stamp`);
    the raw reads, from which every reader re-derives the records, are the same in both."""

    devices: dict[str, DeviceSpec]
    origin: GeoPose | None
    tx_poses: dict[int, GeoPose]
    raw: dict  # the JSON object as read (version, times and summary are checked, read from here)

    @classmethod
    def parse(cls, obj) -> Manifest:
        """The manifest of a parsed JSON value; ValueError saying what is wrong."""
        if not isinstance(obj, dict):
            raise ValueError(f"not a session manifest (a JSON object), got {type_name(obj, 'an object')}")
        if obj.get("format") != FORMAT:
            raise ValueError(f"not an {FORMAT} manifest")
        doc = _typed(obj, _ManifestTable, "")
        if doc.version > FORMAT_VERSION:
            raise ValueError(f"session format {doc.version} is newer than this program reads ({FORMAT_VERSION})")
        devices = {}
        for name, entry in doc.devices.items():
            if not name or "/" in name or "\\" in name or name.startswith("."):
                raise ValueError(f"devices.{name}: {name!r} is not a device name (it names a file in the session)")
            named = {**entry, "name": name} if isinstance(entry, dict) else entry
            devices[name] = dev = _typed(named, DeviceSpec, f"devices.{name}")
            if dev.format is not None and dev.format not in FORMATS.get(dev.kind, ()):
                raise ValueError(f"devices.{name}.format: a {dev.kind} device cannot speak {json.dumps(dev.format)}")
        if not devices:
            raise ValueError("devices: none listed (a session logs at least one device)")
        for tx in doc.tx_poses:
            if not tx.isdigit():
                raise ValueError(f"tx_poses: {tx!r} is not a transmitter ID")
        poses = {int(tx): _typed(pose, GeoPose, f"tx_poses.{tx}") for tx, pose in doc.tx_poses.items()}
        for key, text in (("start_utc", doc.start_utc), ("stop_utc", doc.stop_utc)):
            try:
                text is None or parse_utc(text)
            except ValueError:
                raise ValueError(f"{key}: expected a UTC time like 2026-01-15T10:00:00.000000Z, "
                                 f"got {json.dumps(text)}") from None
        return cls(devices, doc.origin, poses, obj)


# -- reading ------------------------------------------------------------------------
#: Caps of the session readers. None of them ever holds a whole file: each reads one line
#: at a time, and a line (or a manifest) above its cap is refused, naming the line.
#: The logger reads at most 65,537 bytes at once (bench.ingest.reader.READ_CHUNK + 1): a
#: read of more than MAX_READ_BYTES is not one of ours.
MAX_READ_BYTES = 1 << 20
#: Longest ``.raw`` line (bytes, without its newline): two stamps and the base64 of a read.
MAX_RAW_LINE = 4 * ((MAX_READ_BYTES + 2) // 3) + 64
#: Longest ``.jsonl`` line (bytes): a record, an event (a stop event holds every counter).
MAX_JSONL_LINE = 1 << 20
#: Largest manifest (bytes): the logger's is a few kB (plus MANIFEST_RESERVE padding).
MAX_MANIFEST_BYTES = 1 << 20
#: Deepest nesting of objects and lists in a manifest (the logger's is 4 deep).
MAX_JSON_DEPTH = 32

#: Stamps. A ``.raw`` line's ``mono`` must be a finite number; within a device it may go
#: back by at most MONO_TOLERANCE s (the logger writes a device's reads in order); the
#: monotonic time elapsed since the session's first read (the earliest first read of any
#: device) may exceed the wall time elapsed by at most CLOCK_TOLERANCE s (monotonic time
#: never runs ahead of wall time; it falls behind in a suspend, which is allowed); and a
#: read's wall time lies within -CLOCK_TOLERANCE .. MAX_SESSION_SPAN s of the first read's.
MONO_TOLERANCE = 0.001
CLOCK_TOLERANCE = 60.0
MAX_SESSION_SPAN = 365.0 * 86400.0


def _lines(path: Path, cap: int, what: str) -> Iterator[tuple[int, bytes, bool]]:
    """``(line number, line without its newline, ended by a newline)`` of a regular file,
    one at a time; a line longer than ``cap`` bytes is an :class:`InputError`."""
    with open_regular(path, "log file") as f:
        number = 0
        while True:
            line = f.readline(cap + 1)
            if not line:
                return
            number += 1
            complete = line.endswith(b"\n")
            if complete:
                line = line[:-1]
            elif len(line) > cap:
                raise InputError(f"{path}: line {number}: longer than {cap} bytes (not a {what} line)")
            yield number, line, complete


def json_depth(obj: object) -> int:
    """How deep lists and objects nest in a parsed JSON value (a scalar is 0)."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else None
        if children is not None:
            deepest = max(deepest, depth)
            stack.extend((child, depth + 1) for child in children)
    return deepest


def _json(text: str | bytes, where: str | Path) -> object:
    """JSON ``text`` parsed (``json.JSONDecodeError`` or ``UnicodeDecodeError`` if it is
    not JSON); :class:`InputError` naming ``where`` when it nests more than
    :data:`MAX_JSON_DEPTH` deep (a deeper text exhausts the parser's recursion first)."""
    with contextlib.suppress(RecursionError):
        obj = json.loads(text)
        if json_depth(obj) <= MAX_JSON_DEPTH:
            return obj
    raise InputError(f"{where}: JSON nested more than {MAX_JSON_DEPTH} deep")


@dataclass(frozen=True, slots=True)
class Read:
    """One read of a device, stamped at its return: ``mono`` (s, the logger's monotonic
    clock), ``utc`` (POSIX s), ``data`` (empty for records an idle link or the end
    released), and the ``records`` it completed (none in a raw log: its line holds the rest)."""

    mono: float
    utc: float
    data: bytes
    records: Sequence[Stamped] = ()


@dataclass
class RawFile:
    """A device's raw log: its reads, and whether the last line was torn."""

    reads: list[Read]
    torn_tail: bool


@dataclass(frozen=True)
class SessionClock:
    """The reference of a session's stamps: its first read (the earliest ``mono`` of any
    device's first read) and that read's ``utc``. See the stamp rules above."""

    mono: float
    utc: float

    def check(self, path: Path, line: int, read: Read, previous: Read | None) -> None:
        """:class:`InputError` naming ``path`` and ``line`` when ``read``'s stamps break a rule."""
        where = f"{path}: line {line}"
        if not math.isfinite(read.mono):
            raise InputError(f"{where}: stamp {read.mono!r}: not a finite number of seconds")
        if previous is not None and read.mono < previous.mono - MONO_TOLERANCE:
            raise InputError(f"{where}: stamp {read.mono!r} goes back {previous.mono - read.mono:.6g} s "
                             f"(more than {MONO_TOLERANCE:g} s)")  # fmt: skip
        wall = read.utc - self.utc
        if not -CLOCK_TOLERANCE <= wall <= MAX_SESSION_SPAN:
            raise InputError(f"{where}: wall time {utc_iso(read.utc)} is {wall:.6g} s from the session's first read "
                             f"(outside -{CLOCK_TOLERANCE:g} .. {MAX_SESSION_SPAN:g} s)")  # fmt: skip
        ahead = (read.mono - self.mono) - wall
        if ahead > CLOCK_TOLERANCE:
            raise InputError(f"{where}: stamp {read.mono!r} runs {ahead:.6g} s ahead of the wall time since the "
                             f"session's first read (more than {CLOCK_TOLERANCE:g} s)")  # fmt: skip


class RawLog:
    """One device's ``<name>.raw``, read as a stream of :class:`Read` (never whole).

    Every pass (``for read in log``) reads the file again, one line at a time (at most
    :data:`MAX_RAW_LINE` bytes), checks each read's stamps against ``clock`` when one is
    given (:class:`SessionClock`), and leaves what it saw in ``reads``, ``bytes``,
    ``first``, ``last`` and ``torn_tail``. A torn tail (a last line without its newline,
    or trailing lines that do not parse, as a SIGKILL or a power cut may leave) is
    skipped and reported in ``torn_tail``; an unparseable line followed by good ones is
    an :class:`InputError` naming the line, as is a stamp that breaks a rule.
    """

    # What the last pass saw (the values before any).
    reads = bytes = 0
    first: Read | None = None
    last: Read | None = None
    torn_tail = False

    def __init__(self, path: str | Path, clock: SessionClock | None = None) -> None:
        self.path = Path(path)
        self.clock = clock

    def __iter__(self) -> Iterator[Read]:
        path, clock = self.path, self.clock
        self.reads = self.bytes = 0
        self.first = self.last = None
        self.torn_tail = False
        bad: tuple[int, Exception] | None = None
        previous: Read | None = None
        for number, line, complete in _lines(path, MAX_RAW_LINE, "raw log"):
            if not complete:
                self.torn_tail = True
                return
            if not line:
                continue
            try:
                mono, utc, b64 = line.split(b"\t")
                read = Read(float(mono), parse_utc(utc.decode()), base64.b64decode(b64, validate=True))
            except (ValueError, binascii.Error) as exc:
                bad = bad or (number, exc)
                continue
            if bad is not None:  # a good line after a bad one: the bad one is not a torn tail
                raise InputError(f"{path}: line {bad[0]}: not a raw record ({bad[1]})")
            if clock is not None:
                clock.check(path, number, read, previous)
            previous = read
            self.reads += 1
            self.bytes += len(read.data)
            if self.first is None:
                self.first = read
            self.last = read
            yield read
        self.torn_tail = bad is not None

    def scan(self) -> RawLog:
        """One whole pass (validating every line); returns self."""
        for _ in self:
            pass
        return self


def read_raw(path: str | Path) -> RawFile:
    """All reads in a ``.raw`` file, in a list (small files: tests, tools); the commands
    stream with :class:`RawLog`."""
    log = RawLog(path)
    return RawFile(list(log), log.torn_tail)  # torn_tail once the pass is over


def raw_path(directory: str | Path, name: str) -> Path | None:
    """``<directory>/<name>.raw``, or None when it does not exist (a device that never
    delivered a byte); :class:`InputError` when it cannot be looked at (a symbolic link
    loop, a dangling link, a name too long)."""
    path = Path(directory) / f"{name}.raw"
    try:
        os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise InputError(f"{path}: a symbolic link to nothing ({os.readlink(path)})") from None
        return None
    except OSError as exc:
        raise InputError(f"{path}: unreadable: {exc.strerror or exc}") from None
    return path


def session_logs(directory: str | Path, names: Iterable[str]) -> dict[str, RawLog]:
    """The raw logs of the devices ``names`` that logged something, keyed by name, each
    checked against the session's clock (its earliest first read: :class:`SessionClock`)."""
    paths = {name: p for name in names if (p := raw_path(directory, name)) is not None}
    # Each log's first read with a finite ``mono``, unchecked (there is no clock yet).
    firsts = [next((r for r in RawLog(p) if math.isfinite(r.mono)), None) for p in paths.values()]
    if not any(firsts):
        return {name: RawLog(p) for name, p in paths.items()}  # no read anywhere: nothing to check
    ref = min((r for r in firsts if r is not None), key=lambda r: r.mono)
    clock = SessionClock(ref.mono, ref.utc)
    return {name: RawLog(p, clock) for name, p in paths.items()}


def read_jsonl(path: str | Path) -> Iterator[dict]:
    """Objects of a ``.jsonl`` file, one line at a time (at most :data:`MAX_JSONL_LINE`
    bytes, :data:`MAX_JSON_DEPTH` deep); a torn last line is skipped."""
    for number, line, complete in _lines(Path(path), MAX_JSONL_LINE, "JSON lines"):
        if not line:
            continue
        try:
            obj = _json(line, f"{path}: line {number}")
        except InputError:  # nested too deep
            raise
        except ValueError:  # not JSON (incl. an integer of over 4300 digits), or not UTF-8
            if not complete:  # the torn tail
                return
            raise InputError(f"{path}: line {number}: not JSON") from None
        yield obj


def read_manifest(directory: str | Path) -> dict:
    """The manifest of a session as a JSON object, validated (:func:`load_manifest`)."""
    return load_manifest(directory).raw


def load_manifest(directory: str | Path) -> Manifest:
    """The typed manifest of a session directory; :class:`InputError` with one line naming
    the file and the problem for anything that is not a session this program reads (incl.
    a manifest that is not a regular file, larger than :data:`MAX_MANIFEST_BYTES`, or
    nested more than :data:`MAX_JSON_DEPTH` deep)."""
    path = Path(directory) / MANIFEST
    try:
        os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{directory}: not a session directory (no {MANIFEST})") from None
    except OSError:
        pass  # read_regular says why
    data = read_regular(path, MAX_MANIFEST_BYTES, "manifest file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        obj = _json(text, path)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON (line {exc.lineno} column {exc.colno}: {exc.msg})") from None
    try:
        return Manifest.parse(obj)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
