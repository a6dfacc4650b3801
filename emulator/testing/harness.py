"""The harness: ``arva-emulate`` in a subprocess on ptys, and its control channel.

Everything blocking has a deadline: starting (the announcement lines), every control
reply, every line read, stopping (quit, then SIGTERM, then SIGKILL). Nothing here
imports numpy (pyserial, a core dependency, comes with emulator.output.ports: 3 ms).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import serial

from emulator.child_process import end_with_parent, module_command, module_env
from emulator.output.ports import file_name
from emulator.testing.scene_toml import first_receiver_label, scene_file
from firmware_proto.errors import ArvaError


class EmulatorError(ArvaError, RuntimeError):
    """The emulator could not be started, died, or did not answer in time."""


class ControlReplyError(ArvaError, RuntimeError):
    """The emulator answered a control request with ``{"ok": false, "error": ...}``.

    ``request`` is the request object sent, ``error`` the emulator's one-line reason.
    """

    def __init__(self, request: dict, error: str) -> None:
        self.request = request
        self.error = error
        super().__init__(f"arva-emulate refused {json.dumps(request)}: {error}")


class ControlClient(contextlib.AbstractContextManager):
    """One connection to a control channel (``unix:PATH`` or ``tcp:HOST:PORT``).

    :meth:`request` sends one request and returns its reply (raising
    :class:`ControlReplyError` for an error reply). ``transcript`` (a path) receives
    every line sent (``>``) and received (``<``) with its monotonic time, as it happens.
    """

    def __init__(self, address: str, timeout: float = 30.0, transcript: str | Path | None = None) -> None:
        self.address = address
        self.timeout = timeout
        kind, _, rest = address.partition(":")
        if kind == "unix":
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            target: Any = rest
        elif kind == "tcp":
            host, _, port = rest.rpartition(":")
            host = host[1:-1] if host.startswith("[") else host
            sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
            target = (host, int(port))
        else:
            raise ValueError(f"control address must be unix:PATH or tcp:HOST:PORT, got {address!r}")
        sock.settimeout(timeout)
        try:
            sock.connect(target)
        except OSError as exc:
            sock.close()
            raise EmulatorError(f"cannot connect to the control channel {address}: {exc}") from None
        self._sock = sock
        self._buf = bytearray()
        self._lock = threading.Lock()
        self._transcript = open(transcript, "a", encoding="utf-8") if transcript is not None else None

    def _log(self, direction: str, line: str) -> None:
        if self._transcript is not None:
            self._transcript.write(f"{time.monotonic():.6f} {direction} {line.rstrip()}\n")
            self._transcript.flush()

    def send_line(self, line: bytes) -> dict:
        """Send raw bytes (a line, ``\\n`` added if missing) and return the reply object
        without judging it (for tests of the protocol itself)."""
        if not line.endswith(b"\n"):
            line += b"\n"
        with self._lock:
            self._log(">", line.decode("utf-8", "backslashreplace"))
            try:
                self._sock.sendall(line)
            except OSError as exc:
                raise EmulatorError(f"control channel {self.address}: send failed: {exc}") from None
            reply = self._read_line()
            self._log("<", reply)
        return json.loads(reply)

    def _read_line(self) -> str:
        deadline = time.monotonic() + self.timeout
        while True:
            nl = self._buf.find(b"\n")
            if nl >= 0:
                line = bytes(self._buf[:nl])
                del self._buf[: nl + 1]
                return line.decode("utf-8")
            left = deadline - time.monotonic()
            if left <= 0:
                raise EmulatorError(f"control channel {self.address}: no reply within {self.timeout} s")
            self._sock.settimeout(left)
            try:
                data = self._sock.recv(65536)
            except socket.timeout:
                continue
            except OSError as exc:
                raise EmulatorError(f"control channel {self.address}: {exc}") from None
            if not data:
                raise EmulatorError(f"control channel {self.address}: closed by the emulator")
            self._buf += data

    def request(self, op: str, **fields: Any) -> dict:
        """``{"op": op, **fields}`` -> the reply; :class:`ControlReplyError` if not ok."""
        req = {"op": op, **fields}
        reply = self.send_line(json.dumps(req).encode())
        if not reply.get("ok"):
            raise ControlReplyError(req, str(reply.get("error")))
        return reply

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        self._sock.close()
        if self._transcript is not None:
            self._transcript.close()
            self._transcript = None


class EmulatorProcess(contextlib.AbstractContextManager):
    """``arva-emulate ARGS`` in a subprocess (add ``--port pty`` to get ptys).

    Waits until ``streams`` ptys are announced, and, with ``--control``, the control
    line. ``ports`` maps stream label -> current pty path (updated when a disconnect
    re-creates one), ``control`` is the announced control address or None. A thread
    keeps reading stdout and stderr so the emulator never blocks on them; ``stderr()``
    returns what it wrote so far.
    """

    def __init__(self, *args: str, streams: int = 1, timeout: float = 10.0, env: dict | None = None) -> None:
        self.args = list(args)
        self.proc = subprocess.Popen(  # end_with_parent: no orphan holding ptys after a killed test run
            module_command("emulator.cli", *args), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, bufsize=0, env=module_env(env), preexec_fn=end_with_parent,
        )
        self.ports: dict[str, str] = {}
        self.control: str | None = None
        #: Every announcement line so far (a pty re-created after an unplug is announced again).
        self.announcements: list[str] = []
        self._err = bytearray()
        self._announced = threading.Condition()
        self._readers = [
            threading.Thread(target=self._read_stdout, daemon=True, name="arva-emu-stdout"),
            threading.Thread(target=self._read_stderr, daemon=True, name="arva-emu-stderr"),
        ]
        for t in self._readers:
            t.start()
        want_control = "--control" in args
        missing = lambda: len(self.ports) < streams or (want_control and self.control is None)  # noqa: E731
        deadline = time.monotonic() + timeout
        with self._announced:
            while missing():
                left = deadline - time.monotonic()
                if self.proc.poll() is not None:
                    break
                if left <= 0:
                    self.kill()
                    raise EmulatorError(f"arva-emulate announced nothing within {timeout} s: {self.stderr()!r}")
                self._announced.wait(min(left, 0.1))
        if self.proc.poll() is not None and missing():
            rc = self.proc.wait()
            time.sleep(0.05)  # let the stderr reader take the last line
            raise EmulatorError(f"arva-emulate exited with status {rc}: {self.stderr().strip()}")

    def _read_stdout(self) -> None:
        for raw in iter(self.proc.stdout.readline, b""):
            line = raw.decode("utf-8", "replace").strip()
            label, _, rest = line.partition(" ")
            with self._announced:
                self.announcements.append(line)
                if label == "control":
                    self.control = rest
                elif rest:
                    self.ports[label] = rest
                self._announced.notify_all()

    def wait_announcement(self, count: int, timeout: float = 10.0) -> str:
        """The ``count``-th announcement line (1-based), waiting up to ``timeout`` s."""
        with self._announced:
            if not self._announced.wait_for(lambda: len(self.announcements) >= count, timeout):
                raise EmulatorError(f"no announcement #{count} within {timeout} s: {self.announcements}")
            return self.announcements[count - 1]

    def _read_stderr(self) -> None:
        for chunk in iter(lambda: self.proc.stderr.read(4096), b""):
            self._err += chunk

    def stderr(self) -> str:
        return self._err.decode("utf-8", "replace")

    def open(self, label: str = "arva", timeout: float = 2.0):
        """The stream's pty as a pyserial port (reads time out after ``timeout`` s)."""
        return serial.Serial(self.ports[label], timeout=timeout)

    def wait(self, timeout: float = 10.0) -> int:
        """Wait for the emulator to exit on its own; its exit status."""
        try:
            rc = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise EmulatorError(f"arva-emulate still running after {timeout} s") from None
        for t in self._readers:
            t.join(timeout=2)
        return rc

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> tuple[int, str]:
        """Signal it (SIGTERM: a clean stop), wait; (exit status, stderr)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.wait(timeout)
        except EmulatorError:
            self.kill()
            raise
        return rc, self.stderr()

    def __exit__(self, *exc_info) -> None:
        self.kill()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        for t in self._readers:
            t.join(timeout=2)


@dataclasses.dataclass(eq=False)
class Emulator(contextlib.AbstractContextManager):
    """The handle of an emulator with a control channel (what ``arva_emulator`` returns).

    ``port`` is the first receiver's port (a stable symlink to its pty, which follows a
    simulated unplug, or the ``--arva-port`` device), ``ports`` every stream's
    ({label: path}). Each method is one control request of the same name
    (docs/hil_testing.md) and raises :class:`ControlReplyError` on an error reply.
    """

    process: EmulatorProcess
    client: ControlClient
    ports: dict[str, str]
    scene_path: str | None
    seed: int | None
    #: The folder with stream captures, transcript, symlinks while running (see :meth:`start`).
    artefacts: Path | None = None
    cleanup: Sequence[str | Path] = ()  # folders removed at stop
    _stopped: bool = dataclasses.field(default=False, init=False)

    @classmethod
    def start(cls, scene: str | Path | dict | None = None, clock: str = "step", speed: float = 1.0,
              workdir: str | Path | None = None, arva_port: str | None = None, extra_args: Sequence[str] = (),
              timeout: float = 10.0) -> "Emulator":
        """Start ``arva-emulate --port pty --control unix:... --clock CLOCK``.

        ``scene``: a scene file, a dict with the TOML structure (written to ``workdir``)
        or None for the embedded default. ``workdir`` (default: a temporary folder, removed
        by :meth:`stop`) receives the artefacts docs/hil_testing.md lists. ``arva_port``
        sends the first receiver's stream to that device instead of a pty.
        """
        work = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="arva-emu-"))
        links, capture = work / "pty", work / "streams"
        for folder in (links, capture):
            folder.mkdir(parents=True, exist_ok=True)
        scene_path = scene_file(scene, work)
        seed, first = first_receiver_label(scene_path)
        # A short private folder for the socket: unix socket paths are limited to 107 bytes.
        sock_dir = tempfile.mkdtemp(prefix="arva-ctl-")
        address = f"unix:{sock_dir}/control.sock"
        args = ["--port", "pty", "--link", str(links), "--control", address, "--clock", clock,
                "--speed", repr(float(speed)), "--capture", str(capture)]
        if scene_path is not None:
            args += ["--scene", scene_path]
        if arva_port is not None:
            args += ["--stream", f"{first}={arva_port}"]
        args += list(extra_args)
        proc = None
        try:
            proc = EmulatorProcess(*args, streams=0, timeout=timeout)
            client = ControlClient(proc.control, timeout=max(timeout, 30.0), transcript=work / "control-transcript.txt")
            status = client.request("status")
        except Exception:
            if proc is not None:
                proc.kill()
            shutil.rmtree(sock_dir, ignore_errors=True)
            raise
        ports = {}
        for label, path in status["streams"].items():
            link = links / file_name(label)
            ports[label] = str(link) if path != "-" and os.path.islink(link) else path
        # The socket's folder always goes at stop; a temporary work folder of ours too.
        cleanup = [sock_dir] + ([work] if workdir is None else [])
        return cls(proc, client, ports, scene_path, seed, work, cleanup)

    # --- the control requests -----------------------------------------------------------
    @property
    def port(self) -> str:
        """The first receiver's port."""
        return next(iter(self.ports.values()))

    @property
    def epoch(self) -> int:
        """The next epoch's index (``status``)."""
        return self.status()["epoch"]

    def status(self) -> dict:
        return self.client.request("status")

    def step(self, n: int = 1) -> int:
        """Step clock: write the next ``n`` epochs; returns the next epoch's index."""
        return self.client.request("step", n=n)["epoch"]

    def pause(self) -> int:
        return self.client.request("pause")["epoch"]

    def resume(self) -> int:
        return self.client.request("resume")["epoch"]

    def set_transmitter(self, id: int, position=None, orientation=None, enabled=None) -> int:  # noqa: A002
        fields = _given(position=position, orientation=orientation, enabled=enabled)
        return self.client.request("set_transmitter", id=id, **fields)["epoch"]

    def remove_transmitter(self, id: int) -> int:  # noqa: A002
        return self.client.request("remove_transmitter", id=id)["epoch"]

    def set_receiver(self, position=None, orientation=None, id: int | None = None, path: str | None = None) -> int:  # noqa: A002
        fields = _given(id=id, position=position, orientation=orientation, path=path)
        return self.client.request("set_receiver", **fields)["epoch"]

    def fault(self, kind: str, stream: str = "arva", **params) -> int:
        return self.client.request("fault", stream=stream, kind=kind, **params)["epoch"]

    def truth(self) -> dict:
        """``{"epoch", "t", "receivers": [...], "transmitters": [...]}`` of the next epoch."""
        reply = self.client.request("truth")
        reply.pop("ok", None)
        return reply

    def request(self, op: str, **fields) -> dict:
        """Any control request (the reply object)."""
        return self.client.request(op, **fields)

    def open(self, label: str | None = None, timeout: float = 2.0):
        """A stream's port opened with pyserial (default: the first receiver's)."""
        return serial.Serial(self.ports[label] if label else self.port, timeout=timeout)

    # --- stopping -----------------------------------------------------------------------
    def stop(self, timeout: float = 10.0) -> int:
        """``quit``, wait for the exit (SIGTERM, then SIGKILL if it hangs); exit status."""
        if self._stopped:
            return self.process.proc.returncode if self.process.proc.returncode is not None else 0
        self._stopped = True
        try:
            if self.process.proc.poll() is None:
                with contextlib.suppress(EmulatorError, ControlReplyError, OSError):
                    self.client.request("quit")
            try:
                return self.process.wait(timeout)
            except EmulatorError:
                return self.process.stop(signal.SIGTERM, timeout)[0]
        finally:
            self.process.kill()
            self.client.close()
            for folder in self.cleanup:
                shutil.rmtree(folder, ignore_errors=True)
            if self.artefacts is not None:
                # Its symlinks went with the ptys: no empty folder among the artefacts.
                with contextlib.suppress(OSError):
                    (self.artefacts / "pty").rmdir()

    def __exit__(self, *exc) -> None:
        self.stop()


def _given(**fields) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in fields.items() if v is not None}


def read_lines(ser, count: int, timeout: float = 10.0) -> list[bytes]:
    """``count`` CR LF terminated lines from a pyserial port, or TimeoutError after
    ``timeout`` seconds."""
    lines: list[bytes] = []
    deadline = time.monotonic() + timeout
    while len(lines) < count:
        if time.monotonic() > deadline:
            raise TimeoutError(f"got {len(lines)} of {count} lines: {lines!r}")
        line = ser.read_until(b"\r\n")
        if line:
            lines.append(line)
    return lines


def process_rss_kb(pid: int) -> int:
    """Resident memory of a process, kB (Linux /proc)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS")
