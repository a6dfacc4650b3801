"""``--realtime-workers`` (issue 20): the keeper that runs a pty's kernel workers at SCHED_FIFO.

The keeper's logic runs here on a fake /proc and a fake scheduler; two runs of the real
emulator check the kernel side: raised during the run and put back after it (even after
SIGKILL), or exactly one line saying why not.
"""

import errno
import io
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from scene_builders import default_scene_text

from emulator.output import kworkers

EMULATE = Path(sys.executable).with_name("arva-emulate")


def fake_proc(tmp_path: Path, children: dict[int, str], kthreadd: str = "kthreadd") -> Path:
    proc = tmp_path / "proc"
    (proc / "2" / "task" / "2").mkdir(parents=True)
    (proc / "2" / "comm").write_text(kthreadd + "\n")
    (proc / "2" / "task" / "2" / "children").write_text(" ".join(map(str, children)) + " \n")
    for pid, name in children.items():
        if name is not None:
            (proc / str(pid)).mkdir()
            (proc / str(pid) / "comm").write_text(name + "\n")
    return proc


class FakeSched(kworkers.Sched):
    """pid -> [policy, nice, rt priority]; ``refuse``: pids whose change raises EPERM."""

    def __init__(self, threads: dict[int, list[int]], refuse=()) -> None:
        self.threads = threads
        self.refuse = set(refuse)
        self.calls: list[tuple[int, int, int]] = []

    def _get(self, pid):
        if pid not in self.threads:
            raise ProcessLookupError(errno.ESRCH, "No such process")
        return self.threads[pid]

    def policy(self, pid):
        return self._get(pid)[0]

    def nice(self, pid):
        return self._get(pid)[1]

    def priority(self, pid):
        return self._get(pid)[2]

    def set(self, pid, policy, priority):
        self._get(pid)
        if pid in self.refuse:
            raise PermissionError(errno.EPERM, "Operation not permitted")
        self.calls.append((pid, policy, priority))
        self.threads[pid][0] = policy
        self.threads[pid][2] = priority


OTHER, FIFO = os.SCHED_OTHER, os.SCHED_FIFO
WORKERS = {
    3: "rcu_gp",
    10: "kworker/0:1H-kblockd",  # a per-CPU (bound) worker: not the pty's
    576: "kworker/u8:0-events_unbound",
    18817: "kworker/u8:1",
    23924: "kworker/u9:0",  # the nice -20 unbound pool
    40: None,  # exited between the children list and its comm
}


def test_unbound_workers_are_the_kworker_u_children_of_kthreadd(tmp_path):
    proc = fake_proc(tmp_path, WORKERS)
    assert kworkers.unbound_workers(proc) == [
        (576, "kworker/u8:0-events_unbound"), (18817, "kworker/u8:1"), (23924, "kworker/u9:0")]


def test_without_the_children_file_the_parents_are_read_from_stat(tmp_path):
    proc = fake_proc(tmp_path, WORKERS)
    (proc / "2" / "task" / "2" / "children").unlink()
    for pid in (10, 576, 18817):
        (proc / str(pid) / "stat").write_text(f"{pid} ({(proc / str(pid) / 'comm').read_text().strip()}) I 2 0 0\n")
    (proc / "23924" / "stat").write_text("23924 (kworker/u9:0) I 7 0 0\n")  # not kthreadd's
    (proc / "3" / "stat").write_text("3 (a (odd) name) S 2 0 0\n")
    assert sorted(kworkers.unbound_workers(proc)) == [(576, "kworker/u8:0-events_unbound"), (18817, "kworker/u8:1")]


def test_no_workers_where_pid_2_is_not_kthreadd(tmp_path):
    assert kworkers.unbound_workers(fake_proc(tmp_path, WORKERS, kthreadd="sh")) == []
    assert kworkers.unbound_workers(tmp_path / "nothing") == []


def test_sweep_raises_the_ordinary_pool_only_and_restore_puts_back_what_is_still_ours(tmp_path):
    sched = FakeSched({576: [OTHER, 0, 0], 18817: [OTHER, 0, 0], 23924: [OTHER, -20, 0]})
    keeper = kworkers.Keeper(1, fake_proc(tmp_path, WORKERS), sched)
    assert keeper.sweep() is None
    assert keeper.raised == {576: "kworker/u8:0-events_unbound", 18817: "kworker/u8:1"}
    assert sched.calls == [(576, FIFO, 1), (18817, FIFO, 1)]
    assert keeper.sweep() is None and len(sched.calls) == 2  # nothing raised twice
    sched.threads[18817] = [FIFO, 0, 50]  # someone else's setting since: left alone
    assert keeper.restore() == 1
    assert sched.calls[2:] == [(576, OTHER, 0)]
    assert sched.threads == {576: [OTHER, 0, 0], 18817: [FIFO, 0, 50], 23924: [OTHER, -20, 0]}
    assert keeper.raised == {}


def test_a_worker_that_exits_is_skipped(tmp_path):
    sched = FakeSched({18817: [OTHER, 0, 0], 23924: [OTHER, -20, 0]})  # 576 gone
    keeper = kworkers.Keeper(1, fake_proc(tmp_path, WORKERS), sched)
    assert keeper.sweep() is None and list(keeper.raised) == [18817]
    del sched.threads[18817]
    assert keeper.restore() == 0 and keeper.raised == {}


def test_serve_refused_says_why_and_changes_nothing(tmp_path):
    sched = FakeSched({576: [OTHER, 0, 0], 18817: [OTHER, 0, 0], 23924: [OTHER, -20, 0]}, refuse={18817})
    out = io.StringIO()
    r, w = os.pipe()
    try:
        assert kworkers.serve(kworkers.Keeper(1, fake_proc(tmp_path, WORKERS), sched), r, out) == 0
    finally:
        os.close(r)
        os.close(w)
    assert out.getvalue() == "refused kworker/u8:1: Operation not permitted\n"
    assert sched.threads[576] == [OTHER, 0, 0]  # raised, then put back


def test_serve_with_no_workers_refuses(tmp_path):
    out = io.StringIO()
    keeper = kworkers.Keeper(1, fake_proc(tmp_path, WORKERS, kthreadd="init"), FakeSched({}))
    assert kworkers.serve(keeper, 0, out) == 0
    assert out.getvalue() == "refused no kernel workers visible (no kthreadd at pid 2: a container?)\n"


def test_serve_raises_new_workers_until_stdin_closes_then_restores(tmp_path):
    proc = fake_proc(tmp_path, WORKERS)
    sched = FakeSched({576: [OTHER, 0, 0], 18817: [OTHER, 0, 0], 23924: [OTHER, -20, 0], 777: [OTHER, 0, 0]})
    keeper = kworkers.Keeper(1, proc, sched)
    r, w = os.pipe()
    out = io.StringIO()
    done = threading.Thread(target=kworkers.serve, args=(keeper, r, out, 0.01))
    done.start()
    try:
        deadline = time.monotonic() + 10
        while not out.getvalue() and time.monotonic() < deadline:
            time.sleep(0.005)
        assert out.getvalue() == "raised 2\n"
        # The pool creates a worker: the next look raises it too.
        (proc / "777").mkdir()
        (proc / "777" / "comm").write_text("kworker/u8:5\n")
        (proc / "2" / "task" / "2" / "children").write_text("576 18817 23924 777\n")
        while 777 not in keeper.raised and time.monotonic() < deadline:
            time.sleep(0.005)
        assert sched.threads[777] == [FIFO, 0, 1]
    finally:
        os.close(w)  # the emulator ended
        done.join(timeout=10)
        os.close(r)
    assert not done.is_alive()
    assert sched.threads == {576: [OTHER, 0, 0], 18817: [OTHER, 0, 0], 23924: [OTHER, -20, 0], 777: [OTHER, 0, 0]}


@pytest.mark.subprocess
def test_cli_needs_realtime():
    done = subprocess.run([str(EMULATE), "--realtime-workers", "--port", "-", "--frames", "1"],
                          capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == ("arva-emulate: --realtime-workers: needs --realtime "
                           "(the workers are raised only for a real-time run)\n")


def _raised_workers() -> list[str]:
    """Unbound kernel workers of this host now at SCHED_FIFO 1."""
    found = []
    for pid, name in kworkers.unbound_workers():
        try:
            if os.sched_getscheduler(pid) == os.SCHED_FIFO and os.sched_getparam(pid).sched_priority == 1:
                found.append(name)
        except OSError:
            pass
    return found


@pytest.fixture
def scene_20hz(scene_file):
    return Path(scene_file(default_scene_text(rate_hz=20.0)))


@pytest.mark.subprocess
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduler")
def test_real_run_raises_the_workers_and_puts_them_back_even_after_sigkill(scene_20hz):
    """On this host: raised while the emulator runs, back at SCHED_OTHER after SIGKILL;
    or, where not permitted, exactly the one line and the run goes on."""
    assert _raised_workers() == []  # nothing left over from elsewhere
    emu = subprocess.Popen([str(EMULATE), "--scene", str(scene_20hz), "--port", "-", "--frames", "200",
                            "--realtime", "--realtime-workers"], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20
        raised = []
        while not raised and emu.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
            raised = _raised_workers()
        if not raised:  # not permitted here: the run goes on and says why, once
            emu.wait(timeout=30)
            lines = emu.stderr.read().splitlines()
            assert lines[0].startswith("arva-emulate: --realtime-workers: not applied (")
            assert lines[0].endswith("); continuing without it")
            assert lines[-1].startswith("arva-emulate: 200 epochs sent")
            return
        os.kill(emu.pid, signal.SIGKILL)
        emu.wait(timeout=10)
        while _raised_workers() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _raised_workers() == []
    finally:
        if emu.poll() is None:
            emu.kill()
            emu.wait()
        emu.stderr.close()


@pytest.mark.subprocess
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduler")
def test_real_run_to_the_end_emits_the_same_bytes_and_restores(scene_20hz):
    base = [str(EMULATE), "--scene", str(scene_20hz), "--port", "-", "--frames", "4"]
    plain = subprocess.run(base, capture_output=True, timeout=60)
    raised = subprocess.run(base + ["--realtime", "--realtime-workers"], capture_output=True, timeout=60)
    assert raised.returncode == 0 and raised.stdout == plain.stdout
    lines = raised.stderr.decode().splitlines()
    assert lines[-1].startswith("arva-emulate: 4 epochs sent")
    assert all("not permitted" in line for line in lines[:-1]) and len(lines) <= 3
    assert _raised_workers() == []


@pytest.mark.subprocess
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduler")
def test_without_the_permission_one_line_names_the_worker_and_the_run_goes_on(scene_20hz):
    drop = []
    if os.geteuid() == 0:  # root: run without CAP_SYS_NICE, as an ordinary user would
        if shutil.which("setpriv") is None:
            pytest.skip("root without setpriv: cannot drop CAP_SYS_NICE")
        drop = ["setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice"]
    done = subprocess.run(drop + [str(EMULATE), "--scene", str(scene_20hz), "--port", "-", "--frames", "3",
                                  "--realtime", "--realtime-workers"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.count("$PARVA,") == 12
    lines = done.stderr.splitlines()
    # (In a container of its own pid namespace there are no kernel workers to name.)
    assert re.fullmatch(r"arva-emulate: --realtime-workers: not applied \((kworker/u\d+:\d+(-\S+)?: "
                        r"Operation not permitted|no kernel workers visible \(no kthreadd at pid 2: a container\?\))"
                        r"\); continuing without it", lines[0]), lines
    assert lines[-1] == "arva-emulate: 3 epochs sent (arva 3), 0 bytes dropped, 0 faults injected"
    assert _raised_workers() == []


@pytest.mark.subprocess
def test_a_keeper_that_dies_at_start_is_one_line_naming_its_exit_status(monkeypatch):
    monkeypatch.setattr(kworkers.sys, "executable", "/bin/false")
    handle, line = kworkers.raise_workers()
    assert handle is None
    assert line == ("arva-emulate: --realtime-workers: not applied (the keeper process ended without an "
                    "answer (exit status 1)); continuing without it")
