"""``--realtime`` (issue 20): one stderr line when the OS refuses, the run goes on."""

import errno
import subprocess
import sys
from pathlib import Path

import pytest
from scene_builders import default_scene_text

from emulator.output import realtime

pytestmark = pytest.mark.subprocess


class FakeLibc:
    def __init__(self, result: int) -> None:
        self.result = result
        self.flags = None

    def mlockall(self, flags: int) -> int:
        self.flags = flags
        return self.result


@pytest.fixture
def no_side_effects(monkeypatch):
    """Never give the test process itself a real-time class or locked memory."""
    monkeypatch.setattr(realtime.gc, "freeze", lambda: None)
    calls = []
    monkeypatch.setattr(realtime.os, "sched_setscheduler", lambda *a: calls.append(a))
    return calls


def test_refused_requests_give_one_line(monkeypatch, no_side_effects):
    def refuse(*_args):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime.ctypes, "CDLL", lambda *a, **k: FakeLibc(-1))
    monkeypatch.setattr(realtime.ctypes, "get_errno", lambda: errno.ENOMEM)
    result = realtime.request_realtime()
    assert (result.scheduler, result.memory_locked) == (False, False)
    assert result.message() == (
        "arva-emulate: --realtime: not permitted (SCHED_FIFO: Operation not permitted; "
        "mlockall: Cannot allocate memory); continuing without it"
    )


def test_granted_requests_say_nothing(monkeypatch, no_side_effects):
    libc = FakeLibc(0)
    monkeypatch.setattr(realtime.ctypes, "CDLL", lambda *a, **k: libc)
    monkeypatch.setattr(realtime.os, "geteuid", lambda: 1000)
    monkeypatch.setattr(realtime.resource, "getrlimit", lambda _r: (64 * 1024, 64 * 1024))
    result = realtime.request_realtime()
    assert (result.scheduler, result.memory_locked, result.message()) == (True, True, None)
    assert no_side_effects[0][1] == realtime.os.SCHED_FIFO
    # A finite memlock limit for a non-root user: current pages only, so later
    # allocations cannot fail on the limit.
    assert libc.flags == 1


def test_cli_flag_runs_and_emits_the_same_bytes(scene_file):
    path = scene_file(default_scene_text(rate_hz=50.0))
    exe = Path(sys.executable).with_name("arva-emulate")
    base = [str(exe), "--scene", path, "--port", "-", "--frames", "3"]
    plain = subprocess.run(base, capture_output=True, timeout=60)
    rt = subprocess.run(base + ["--realtime"], capture_output=True, timeout=60)
    assert rt.returncode == 0 and rt.stdout == plain.stdout
    # Either granted (silent) or one line saying what was refused; then the summary.
    lines = rt.stderr.decode().splitlines()
    assert lines[-1].startswith("arva-emulate: 3 epochs sent")
    assert len(lines) == 1 or (len(lines) == 2 and "--realtime: not permitted" in lines[0])
