"""``--realtime-workers``: run the kernel workers that carry a pty's bytes at SCHED_FIFO.

Linux only; times in seconds. A pty hands the bytes written on its master to its reader
from a worker of the unbound workqueue (``kworker/uN:M``, a child of ``kthreadd``) at
ordinary priority, so with every core busy the reader waits for that worker's turn
(docs/emulator.md, "Sub-millisecond timing at the device under test"). At SCHED_FIFO
priority 1 the worker runs when the write queues it.

The change is host-wide, so it is opt-in, lasts for the run only, and is kept by a
separate keeper process (``python -m emulator.output.kworkers PRIORITY``) that raises the
pool's workers every ``PERIOD`` s (the pool creates them as it needs them); when its
stdin closes (the emulator ended, even by SIGKILL) it puts back every worker it changed
that is still as it left it, and exits. It ignores SIGINT (the emulator's to handle) and
restores on SIGTERM. Its first line on stdout is ``raised N`` or ``refused REASON`` (then
it exits at once, having changed nothing). A second keeper leaves the first's workers
alone; when the first puts them back, the second raises them again within ``PERIOD``.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from emulator.child_process import module_command, module_env

#: SCHED_FIFO priority given to the workers: above ordinary tasks, below the emulator's
#: ``--realtime`` priority (emulator/output/realtime.py, 20), so the emulator's own
#: deadline still comes first.
PRIORITY = 1
#: Seconds between the keeper's looks for workers the pool created since.
PERIOD = 1.0
#: Seconds the emulator waits for the keeper's first line.
START_TIMEOUT = 10.0

_WORKER = re.compile(r"kworker/u\d+:\d+(?:-.*)?")
_KTHREADD = 2


class Sched:
    """The scheduler calls the keeper makes on other threads (os.*, Linux)."""

    def policy(self, pid: int) -> int:
        return os.sched_getscheduler(pid)

    def nice(self, pid: int) -> int:
        return os.getpriority(os.PRIO_PROCESS, pid)

    def priority(self, pid: int) -> int:
        return os.sched_getparam(pid).sched_priority

    def set(self, pid: int, policy: int, priority: int) -> None:
        os.sched_setscheduler(pid, policy, os.sched_param(priority))


def unbound_workers(proc: Path = Path("/proc")) -> list[tuple[int, str]]:
    """(pid, name) of the unbound workqueue pools' workers: children of kthreadd named
    ``kworker/uN:M`` (with ``-WORKQUEUE`` appended while busy). Empty where kthreadd is
    not pid 2 of this /proc (a container's own pid namespace)."""
    try:
        if (proc / str(_KTHREADD) / "comm").read_text().strip() != "kthreadd":
            return []
    except OSError:
        return []
    try:
        children = (proc / str(_KTHREADD) / "task" / str(_KTHREADD) / "children").read_text().split()
    except OSError:  # a kernel without CONFIG_PROC_CHILDREN: every process's parent instead
        children = [d.name for d in proc.iterdir() if d.name.isdigit() and _parent(d) == _KTHREADD]
    found = []
    for pid in children:
        try:
            name = (proc / pid / "comm").read_text().strip()
        except OSError:
            continue  # the worker exited meanwhile
        if _WORKER.fullmatch(name):
            found.append((int(pid), name))
    return found


def _parent(pid_dir: Path) -> int | None:
    """The parent pid from /proc/PID/stat (after the parenthesised name), or None."""
    try:
        stat = (pid_dir / "stat").read_text()
        return int(stat[stat.rindex(")") + 2 :].split()[1])
    except (OSError, ValueError, IndexError):
        return None


@dataclass
class Keeper:
    """The workers this keeper raised to SCHED_FIFO ``priority``, and how to put them back."""

    priority: int = PRIORITY
    proc: Path = Path("/proc")
    sched: Sched = field(default_factory=Sched)
    raised: dict[int, str] = field(default_factory=dict)

    def sweep(self) -> str | None:
        """Raise every worker of the ordinary unbound pool (SCHED_OTHER, nice 0) not raised
        yet; None, or the first refusal (``NAME: strerror``)."""
        for pid, name in unbound_workers(self.proc):
            if pid in self.raised:
                continue
            try:
                if self.sched.policy(pid) != os.SCHED_OTHER or self.sched.nice(pid) != 0:
                    continue  # another pool (nice -20), or someone else's setting
                self.sched.set(pid, os.SCHED_FIFO, self.priority)
            except ProcessLookupError:
                continue
            except OSError as exc:
                return f"{name}: {exc.strerror or exc}"
            self.raised[pid] = name
        return None

    def restore(self) -> int:
        """SCHED_OTHER again for each raised worker still at SCHED_FIFO ``priority`` (what
        this keeper left); the count put back."""
        restored = 0
        for pid in list(self.raised):
            try:
                if self.sched.policy(pid) == os.SCHED_FIFO and self.sched.priority(pid) == self.priority:
                    self.sched.set(pid, os.SCHED_OTHER, 0)
                    restored += 1
            except OSError:
                pass  # exited, or changed by someone else: not ours to touch
            del self.raised[pid]
        return restored


def serve(keeper: Keeper, stdin_fd: int, out, period: float = PERIOD) -> int:
    """The keeper's loop: first line ``raised N`` / ``refused REASON``; then raise new
    workers every ``period`` s until ``stdin_fd`` reaches end of file; then restore."""
    refused = keeper.sweep()
    if refused is not None:
        keeper.restore()  # a partial sweep changes nothing either
        print(f"refused {refused}", file=out, flush=True)
        return 0
    if not keeper.raised:
        print("refused no kernel workers visible (no kthreadd at pid 2: a container?)", file=out, flush=True)
        return 0
    print(f"raised {len(keeper.raised)}", file=out, flush=True)
    try:
        while True:
            ready, _, _ = select.select([stdin_fd], [], [], period)
            if ready and not os.read(stdin_fd, 4096):
                break
            keeper.sweep()
    finally:
        keeper.restore()
    return 0


class WorkersRaised:
    """The emulator's side: the keeper process, started by :func:`raise_workers`."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self._proc = proc

    def close(self) -> None:
        """Close the keeper's stdin and wait for it to put the workers back."""
        if not self._proc.stdin.closed:
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=START_TIMEOUT)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


def raise_workers(priority: int = PRIORITY, prog: str = "arva-emulate") -> tuple[WorkersRaised | None, str | None]:
    """Start the keeper; (handle to close at the end, None), or (None, the one stderr line
    saying why the workers stay as they are)."""

    def refused(why: str) -> tuple[None, str]:
        return None, f"{prog}: --realtime-workers: not applied ({why}); continuing without it"

    proc = subprocess.Popen(module_command(__name__, str(priority)), stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=module_env(),
                            start_new_session=True)
    ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT)
    first = proc.stdout.readline().decode(errors="replace").strip() if ready else ""
    proc.stdout.close()
    if first.startswith("raised "):
        return WorkersRaised(proc), None
    WorkersRaised(proc).close()  # it has ended, or ends now
    if first.startswith("refused "):
        return refused(first.removeprefix("refused "))
    if not ready:
        return refused(f"the keeper process gave no answer in {START_TIMEOUT:g} s")
    return refused(f"the keeper process ended without an answer (exit status {proc.returncode})")


def main(argv: list[str] | None = None) -> int:
    """``python -m emulator.output.kworkers [PRIORITY]``: the keeper process."""
    argv = sys.argv[1:] if argv is None else argv
    priority = int(argv[0]) if argv else PRIORITY
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # SystemExit runs serve's restore
    # Never keep a real-time class inherited from a --realtime parent.
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    if not hasattr(os, "sched_setscheduler"):
        print("refused not Linux", flush=True)
        return 0
    return serve(Keeper(priority), sys.stdin.fileno(), sys.stdout)


if __name__ == "__main__":
    sys.exit(main())
