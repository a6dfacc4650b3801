"""Crash-safe session directories: every byte read, timestamped, append-only.

Layout of a session directory::

    manifest.json           devices, roles, versions, start/stop, origin (atomic rewrite)
    events.jsonl            start, stop, gaps (unplugged devices), reconnects, disk errors
    <device>.raw            one line per read:  mono_s <TAB> utc_iso <TAB> base64(bytes)
    <device>.jsonl          decoded records derived from the raw bytes (flagged if corrupt)

Every file is line-oriented and append-only; each line is written with one ``write``
and flushed at once (a SIGKILL loses nothing the kernel has), and a background thread
fsyncs dirty files at least once a second (a power cut loses at most the last second).
Readers tolerate a torn last line. ``mono_s`` is ``time.monotonic()`` of the reading
process, for intervals; ``utc_iso`` (``2026-11-22T08:01:02.123456Z``) is wall time.
"""

from __future__ import annotations

import base64
import binascii
import errno
import datetime as _dt
import json
import os
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from firmware_proto.errors import InputError, LinkError

MANIFEST = "manifest.json"
EVENTS = "events.jsonl"
FORMAT = "arva-session"
FORMAT_VERSION = 1


def utc_iso(t: float | None = None) -> str:
    """UTC wall time as ISO 8601 with microseconds and a ``Z``."""
    t = time.time() if t is None else t
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_utc(text: str) -> float:
    return _dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=_dt.timezone.utc).timestamp()


class _AppendFile:
    """One append-only file: whole lines, flushed per line, fsynced by the writer."""

    def __init__(self, path: Path) -> None:
        self.path = path
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


class SessionWriter:
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

    def _write_manifest(self) -> None:
        tmp = self.dir / (MANIFEST + ".tmp")
        data = json.dumps(self.manifest, indent=2, sort_keys=True).encode() + b"\n"
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.dir / MANIFEST)
        dir_fd = os.open(self.dir, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself survives a power cut
        finally:
            os.close(dir_fd)

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
            self.sync()

    def sync(self) -> None:
        with self._files_lock:
            files = list(self._files.values())
        for f in files:
            try:
                f.sync()
            except OSError:
                pass  # reported by the next write to that file

    def close(self, **summary) -> None:
        """Record the stop, fsync everything, and finish the manifest."""
        if self.closed:
            return
        self.closed = True
        try:
            self.event("stop", **summary)
        except LinkError:
            pass  # the disk is full: the manifest rewrite below may still fit
        self._stop.set()
        self._syncer.join(timeout=5)
        with self._files_lock:
            files = list(self._files.values())
        for f in files:
            try:
                f.close()
            except OSError:
                pass
        with self._manifest_lock:
            self.manifest["stop_utc"] = utc_iso()
            if summary:
                self.manifest["summary"] = summary
            try:
                self._write_manifest()
            except OSError:
                pass  # the start manifest is still there


# -- reading ------------------------------------------------------------------------
@dataclass(frozen=True)
class RawRead:
    """One logged read: ``mono`` (s, logger's monotonic clock), ``utc`` (POSIX s)."""

    mono: float
    utc: float
    data: bytes


@dataclass
class RawFile:
    """A device's raw log: its reads, and whether the last line was torn."""

    reads: list[RawRead]
    torn_tail: bool


def _parse_raw_line(line: bytes) -> RawRead:
    mono, utc, b64 = line.split(b"\t")
    return RawRead(float(mono), parse_utc(utc.decode()), base64.b64decode(b64, validate=True))


def read_raw(path: str | Path) -> RawFile:
    """All reads in a ``.raw`` file.

    A torn tail (a last line without its newline, or trailing lines that do not parse,
    as a SIGKILL or a power cut may leave) is skipped and reported in ``torn_tail``; an
    unparseable line followed by good ones is an :class:`InputError` naming the line.
    """
    lines = Path(path).read_bytes().split(b"\n")
    complete, tail = lines[:-1], lines[-1]  # tail is b"" when the file ends in a newline
    reads: list[RawRead] = []
    for i, line in enumerate(complete):
        if not line:
            continue
        try:
            reads.append(_parse_raw_line(line))
        except (ValueError, binascii.Error) as exc:
            if any(_parses(rest) for rest in complete[i + 1 :]):
                raise InputError(f"{path}: line {i + 1}: not a raw record ({exc})") from None
            return RawFile(reads, torn_tail=True)
    return RawFile(reads, torn_tail=bool(tail))


def _parses(line: bytes) -> bool:
    try:
        _parse_raw_line(line)
        return True
    except (ValueError, binascii.Error):
        return False


def read_jsonl(path: str | Path) -> Iterator[dict]:
    """Objects of a ``.jsonl`` file; a torn last line is skipped."""
    lines = Path(path).read_bytes().split(b"\n")
    for i, line in enumerate(lines):
        if not line:
            continue
        try:
            yield json.loads(line)
        except json.JSONDecodeError:
            if i == len(lines) - 1:
                return  # torn tail
            raise InputError(f"{path}: line {i + 1}: not JSON") from None


def read_manifest(directory: str | Path) -> dict:
    path = Path(directory) / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{directory}: not a session directory (no {MANIFEST})") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: unreadable: {exc}") from None
    if manifest.get("format") != FORMAT:
        raise InputError(f"{path}: not an {FORMAT} manifest")
    if manifest.get("version", 0) > FORMAT_VERSION:
        raise InputError(f"{path}: session format {manifest['version']} is newer than this program reads ({FORMAT_VERSION})")
    return manifest
