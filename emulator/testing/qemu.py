"""Firmware in the loop: a microcontroller emulated by QEMU, its UART wired to the emulator.

:class:`Board` runs ``qemu-system-arm -M mps2-an385 -kernel FIRMWARE.elf`` with both
UARTs as ptys: UART0's (:attr:`Board.uart0`) is handed to ``arva-emulate`` as a serial
device (``--stream arva=PATH``), UART1 carries the firmware's own output, read by a
thread into :attr:`Board.lines` and ``uart1.txt``. :class:`FirmwareLoop` is the pair
(board + emulator with its control channel) that the ``arva_firmware`` fixture returns.
docs/hil_testing.md, "Your firmware in the loop", describes the wiring, the files kept
when a test fails, the two clocks (``icount``: the guest clock advances 2**N ns per
instruction) and the Debian packages needed (:class:`ToolMissing` names them).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path

import serial

import firmware_proto

from emulator.child_process import end_with_parent
from emulator.output.ports import file_name

from .harness import Emulator, EmulatorError

QEMU = "qemu-system-arm"
#: The example firmware's sources (search state machine on mps2-an385; its Makefile).
EXAMPLE_FIRMWARE = Path(firmware_proto.__file__).parent / "examples" / "search_fw"
#: Debian packages that provide the tools, by command.
PACKAGES = {
    "qemu-system-arm": "qemu-system-arm",
    "arm-none-eabi-gcc": "gcc-arm-none-eabi libnewlib-arm-none-eabi",
    "make": "make",
}
_REDIRECT = re.compile(r"char device redirected to (\S+) \(label (serial\d+)\)")


class ToolMissing(EmulatorError):
    """A program firmware in the loop needs is not installed (the message says which package)."""

    def __init__(self, command: str) -> None:
        self.command = command
        self.package = PACKAGES.get(command, command)
        super().__init__(f"firmware in the loop needs {command}: install Debian's {self.package} (apt-get install {self.package})")


def missing_tools(commands=("qemu-system-arm", "arm-none-eabi-gcc", "make")) -> list[str]:
    """The commands of ``commands`` that are not on PATH."""
    return [c for c in commands if shutil.which(c) is None]


def build_firmware(source_dir: str | Path, out_dir: str | Path, target: str = "search_fw.elf", timeout: float = 120.0) -> Path:
    """``make -C source_dir OUT=out_dir``: the ELF's path. The build log (with the size and
    stack figures the example's Makefile prints) is kept as ``out_dir/build.log``."""
    for tool in ("make", "arm-none-eabi-gcc"):
        if shutil.which(tool) is None:
            raise ToolMissing(tool)
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        ["make", "-C", str(source_dir), f"OUT={out}"], capture_output=True, text=True, timeout=timeout
    )
    (out / "build.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise EmulatorError(f"building the firmware in {source_dir} failed: {last} (log: {out / 'build.log'})")
    return out / target


class Board(AbstractContextManager):
    """``qemu-system-arm`` running one firmware; see the module docstring."""

    def __init__(self, firmware: str | Path, workdir: str | Path, machine: str = "mps2-an385",
                 icount: int | None = None, timeout: float = 10.0) -> None:
        if shutil.which(QEMU) is None:
            raise ToolMissing(QEMU)
        firmware = Path(firmware)
        if not firmware.is_file():
            raise EmulatorError(f"{firmware}: no such firmware image")
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        args = [
            QEMU, "-M", machine, "-display", "none", "-monitor", "none", "-kernel", str(firmware),
            "-serial", "pty", "-serial", "pty", "-d", "guest_errors,unimp", "-D", str(self.workdir / "qemu.log"),
        ]
        if icount is not None:
            args += ["-icount", f"shift={int(icount)},align=off,sleep=off"]
        self.args = args
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._out = open(self.workdir / "qemu-stdout.txt", "w")
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, preexec_fn=end_with_parent)
        ptys: dict[str, str] = {}
        deadline = time.monotonic() + timeout
        try:
            while len(ptys) < 2:  # QEMU prints one line per pty before the guest starts
                line = self.proc.stdout.readline()
                if not line:
                    rc = self.proc.wait(timeout=5)
                    raise EmulatorError(f"{QEMU} exited with status {rc} before opening its UARTs (see {self.workdir / 'qemu-stdout.txt'})")
                self._out.write(line)
                m = _REDIRECT.search(line)
                if m:
                    ptys[m.group(2)] = m.group(1)
                if time.monotonic() > deadline:
                    raise EmulatorError(f"{QEMU} announced no UART ptys within {timeout} s")
        except BaseException:
            self._out.flush()
            self.stop()
            raise
        self._out.flush()
        self.uart0, self.uart1 = ptys["serial0"], ptys["serial1"]
        self._port = serial.Serial(self.uart1, timeout=0.05)  # pyserial's open makes the pty raw
        self._threads = [
            threading.Thread(target=self._read_uart1, daemon=True, name="qemu-uart1"),
            threading.Thread(target=self._drain_stdout, daemon=True, name="qemu-stdout"),
        ]
        for t in self._threads:
            t.start()

    def _drain_stdout(self) -> None:
        for line in iter(self.proc.stdout.readline, ""):
            self._out.write(line)
            self._out.flush()

    def _read_uart1(self) -> None:
        pending = b""
        with open(self.workdir / "uart1.txt", "wb", buffering=0) as log:
            while not self._stop.is_set():
                try:  # the first byte waits (up to the timeout), the rest is what has arrived
                    chunk = self._port.read(1)
                    if chunk:
                        chunk += self._port.read(self._port.in_waiting)
                except Exception:  # noqa: BLE001 - QEMU went away: the board is over
                    break
                if not chunk:
                    continue
                log.write(chunk)
                pending += chunk
                *done, pending = pending.split(b"\n")
                if done:
                    with self._cond:
                        self.lines.extend(d.decode("utf-8", "replace").rstrip("\r") for d in done)
                        self._cond.notify_all()

    def wait_for(self, predicate: Callable[[list[str]], bool], timeout: float = 10.0) -> list[str]:
        """Wait until ``predicate(lines)`` holds; the lines so far. Raises ``TimeoutError``
        naming the last lines when it does not within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate(self.lines):
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    why = "QEMU exited" if self.proc.poll() is not None else f"timed out after {timeout} s"
                    raise TimeoutError(f"firmware output: {why}; last lines: {self.lines[-3:]}")
                self._cond.wait(min(left, 0.1))
            return list(self.lines)

    def stop(self, timeout: float = 5.0) -> None:
        """End QEMU (SIGTERM, then SIGKILL) and the reader threads."""
        self._stop.set()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout)
        for t in getattr(self, "_threads", []):
            t.join(timeout=2)
        port = getattr(self, "_port", None)
        if port is not None:
            port.close()
        self._out.close()

    def __exit__(self, *exc) -> None:
        self.stop()


class FirmwareLoop(AbstractContextManager):
    """A :class:`Board` whose UART0 the emulator ``emu`` writes the receiver stream into.

    ``decisions()`` parses the firmware's JSON lines that carry a ``seq``; ``decision(seq)``
    waits for the one of epoch ``seq``."""

    def __init__(self, board: Board, emu: Emulator, cleanup: Path | None = None) -> None:
        self.board, self.emu = board, emu
        self._cleanup = cleanup  # a temporary work folder of ours, removed at stop
        self._decisions: list[dict] = []
        self._lines_parsed = 0

    @classmethod
    def start(cls, firmware, scene=None, clock: str = "step", speed: float = 1.0, workdir=None, machine: str = "mps2-an385", icount: int | None = None) -> "FirmwareLoop":
        work = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="arva-fw-"))
        ours = work if workdir is None else None  # a temporary folder, removed at stop
        board = Board(firmware, work, machine=machine, icount=icount)
        try:
            emu = Emulator.start(scene, clock=clock, speed=speed, workdir=work / "emulator", arva_port=board.uart0)
        except BaseException:
            board.stop()
            if ours is not None:
                shutil.rmtree(ours, ignore_errors=True)
            raise
        return cls(board, emu, ours)

    def decisions(self) -> list[dict]:
        """The JSON lines with a ``seq`` so far; each line is parsed once (the board's
        lines only grow), so waiting for the n-th decision is not quadratic."""
        lines = self.board.lines
        for line in lines[self._lines_parsed : len(lines)]:
            self._lines_parsed += 1
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            if isinstance(msg, dict) and "seq" in msg:
                self._decisions.append(msg)
        return list(self._decisions)

    def decision(self, seq: int, timeout: float = 10.0) -> dict:
        self.board.wait_for(lambda _lines: any(d["seq"] == seq for d in self.decisions()), timeout)
        return next(d for d in reversed(self.decisions()) if d["seq"] == seq)

    def captured(self, stream: str = "arva") -> bytes:
        """Every byte the emulator offered the firmware's UART0 so far (after faults)."""
        path = self.emu.artefacts / "streams" / f"{file_name(stream)}.bytes"
        return path.read_bytes() if path.exists() else b""

    def stop(self) -> None:
        """Stop the emulator and the board; a temporary work folder (``workdir=None``) goes too."""
        try:
            self.emu.stop()
        finally:
            self.board.stop()
            if self._cleanup is not None:
                shutil.rmtree(self._cleanup, ignore_errors=True)

    def __exit__(self, *exc) -> None:
        self.stop()
