"""A test process killed with SIGKILL (a CI job's timeout) leaves no QEMU and no
emulator behind: Board and EmulatorProcess start them with PR_SET_PDEATHSIG
(emulator.child_process.end_with_parent). Every wait is bounded."""

import os
import signal
import subprocess
import sys
import time

import pytest

from emulator.testing.qemu import missing_tools

pytestmark = pytest.mark.subprocess


EMULATOR_CHILD = """
import time
from emulator.testing import EmulatorProcess
emu = EmulatorProcess("--port", "pty", "--speed", "1")
print(emu.proc.pid, flush=True)
time.sleep(60)
"""

QEMU_CHILD = """
import sys, time
from emulator.testing.qemu import EXAMPLE_FIRMWARE, Board, build_firmware
board = Board(build_firmware(EXAMPLE_FIRMWARE, sys.argv[1] + "/build"), sys.argv[1] + "/work")
print(board.proc.pid, flush=True)
time.sleep(60)
"""


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False


def grandchild_outlives_a_killed_parent(code: str, tmp_path) -> bool:
    """Run ``code`` (it prints the pid of what it starts), SIGKILL it, and say whether
    that grandchild is still running 10 s later."""
    child = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    pid = None
    try:
        pid = int(child.stdout.readline())
        assert alive(pid)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
        deadline = time.monotonic() + 10
        while alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        return alive(pid)
    finally:
        child.kill()
        child.wait(timeout=10)
        if pid is not None and alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_the_emulator_ends_when_the_test_process_is_killed(tmp_path):
    assert not grandchild_outlives_a_killed_parent(EMULATOR_CHILD, tmp_path)


@pytest.mark.skipif(bool(missing_tools()), reason="firmware in the loop needs qemu-system-arm, gcc-arm-none-eabi "
                    "and make (make test installs them as root)")
@pytest.mark.timeout(120)
def test_qemu_ends_when_the_test_process_is_killed(tmp_path):
    assert not grandchild_outlives_a_killed_parent(QEMU_CHILD, tmp_path)
