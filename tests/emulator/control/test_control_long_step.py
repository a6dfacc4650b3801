"""A long ``step`` does not starve the control channel (issue 29): it is written
``STEP_SLICE`` epochs at a time, the other clients' requests are served between two
slices, its one reply comes after its last epoch, and SIGTERM or another client's
``quit`` still ends the emulator at once (the step's client is told how far it got).
Every read has a deadline."""

import json
import re
import signal
import socket
import subprocess
import sys
import time
import weakref

import pytest
from scene_builders import one_tx

from emulator.control.controller import STEP_SLICE
from emulator.testing import ControlClient, EmulatorProcess
from emulator.testing.scene_toml import dumps

pytestmark = pytest.mark.subprocess

ONE = one_tx(rate_hz=1.0)
BIG = 1_000_000  # the documented maximum of one step: minutes of work


def start(tmp_path, *extra):
    scene = tmp_path / "s.toml"
    scene.write_text(dumps(ONE))
    return EmulatorProcess("--scene", str(scene), "--port", "pty", "--clock", "step",
                           "--control", f"unix:{tmp_path}/c.sock", *extra)


def raw_client(emu) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX)
    sock.settimeout(10)
    sock.connect(emu.control.removeprefix("unix:"))
    return sock


_pending: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # bytes read past a reply, per socket


def read_reply(sock: socket.socket, timeout: float = 10.0) -> dict:
    """The next reply line on ``sock`` (replies to pipelined requests may arrive together)."""
    sock.settimeout(timeout)
    data = _pending.pop(sock, b"")
    while b"\n" not in data:
        chunk = sock.recv(4096)
        assert chunk, f"closed without a reply after {data!r}"
        data += chunk
    line, _, rest = data.partition(b"\n")
    _pending[sock] = rest
    return json.loads(line)


@pytest.mark.timeout(60)
def test_other_clients_are_answered_during_a_big_step_and_sigterm_ends_it(tmp_path):
    emu = start(tmp_path)
    try:
        stepper = raw_client(emu)
        stepper.sendall(json.dumps({"op": "step", "n": BIG}).encode() + b"\n")
        other = ControlClient(emu.control, timeout=1.0)  # each reply within 1 s, or EmulatorError
        seen = []
        for _ in range(6):
            t0 = time.monotonic()
            seen.append(other.request("status")["epoch"])
            assert time.monotonic() - t0 < 1.0
            time.sleep(0.15)
        assert seen == sorted(seen) and seen[-1] > seen[0] and seen[-1] < BIG  # the step runs meanwhile
        t0 = time.monotonic()
        emu.proc.send_signal(signal.SIGTERM)
        rc = emu.wait(timeout=10)
        assert time.monotonic() - t0 < 3.0 and rc == 0
        reply = read_reply(stepper)
        done = int(re.fullmatch(rf"step: the emulator is stopping: stopped after (\d+) of {BIG} epochs",
                                reply.pop("error")).group(1))
        assert reply == {"ok": False} and seen[-1] <= done < BIG
        # What the reply says was written is what the summary counts.
        assert emu.stderr().splitlines()[-1].startswith(f"arva-emulate: {done} epochs sent (arva {done}),")
        other.close()
        stepper.close()
    finally:
        emu.kill()


@pytest.mark.timeout(60)
def test_quit_from_another_client_ends_a_big_step(tmp_path):
    emu = start(tmp_path)
    try:
        stepper = raw_client(emu)
        stepper.sendall(b'{"op": "step", "n": 1000000}\n')
        time.sleep(0.3)
        quitter = ControlClient(emu.control, timeout=2.0)
        assert quitter.request("quit") == {"ok": True}
        assert emu.wait(timeout=5) == 0
        assert re.fullmatch(r"step: the emulator is stopping: stopped after \d+ of 1000000 epochs",
                            read_reply(stepper)["error"])
        quitter.close()
        stepper.close()
    finally:
        emu.kill()


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_sliced_steps_queue_keep_their_order_and_write_the_free_run_bytes(tmp_path):
    """Client a pipelines a step of many slices and a status; client b's step, sent while
    a's runs, waits for it. Replies: one per request, in order; the bytes offered to the
    port are exactly a free run's of as many epochs."""
    (tmp_path / "cap").mkdir()
    emu = start(tmp_path, "--capture", str(tmp_path / "cap"))
    n_a, n_b = STEP_SLICE * 20 + 50, STEP_SLICE + 30
    try:
        a, b = raw_client(emu), raw_client(emu)
        watcher = ControlClient(emu.control, timeout=1.0)
        a.sendall(json.dumps({"op": "step", "n": n_a}).encode() + b'\n{"op": "status"}\n')
        deadline = time.monotonic() + 10
        while watcher.request("status")["epoch"] == 0:  # a's step has begun
            assert time.monotonic() < deadline
        b.sendall(json.dumps({"op": "step", "n": n_b}).encode() + b"\n")
        assert read_reply(a) == {"ok": True, "epoch": n_a}
        assert n_a <= read_reply(a)["epoch"] <= n_a + n_b  # a's status, after its step
        assert read_reply(b) == {"ok": True, "epoch": n_a + n_b}
        assert watcher.request("quit") == {"ok": True}
        assert emu.wait(timeout=10) == 0
        for sock in (a, b):
            sock.close()
        watcher.close()
    finally:
        emu.kill()
    free = subprocess.run([sys.executable, "-m", "emulator.cli", "--scene", str(tmp_path / "s.toml"), "--port", "-",
                           "--frames", str(n_a + n_b), "--speed", "0"], capture_output=True, timeout=60)
    assert free.returncode == 0
    assert (tmp_path / "cap" / "arva.bytes").read_bytes() == free.stdout
