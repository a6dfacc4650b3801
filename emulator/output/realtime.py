"""``--realtime``: ask the OS for a real-time scheduling class and locked memory.

Real-time epochs are written at deadlines on the monotonic clock (seconds). SCHED_FIFO
makes this process preempt ordinary tasks when its sleep ends, and ``mlockall`` keeps
its pages resident so a deadline never waits on a page fault. Both need privileges
(root, CAP_SYS_NICE / CAP_IPC_LOCK, or an rtprio / memlock limit); where refused the
emulator runs as before and says so in one stderr line. Linux's RT throttling
(sched_rt_runtime_us) still caps a real-time task below a whole core, and the scheduler sleeps
between epochs, so this never starves the host. What it cannot help (a hypervisor's
steal time, a pty's kernel worker: emulator/output/kworkers.py): docs/emulator.md,
"Sub-millisecond timing at the device under test".
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import resource
from dataclasses import dataclass

#: SCHED_FIFO priority asked for (1..99): above every ordinary task, below kernel threads'
#: usual real-time priorities (50) so interrupt handling stays ahead of us.
PRIORITY = 20
_MCL_CURRENT, _MCL_FUTURE = 1, 2


@dataclass(frozen=True)
class RealtimeResult:
    """What was granted; ``refused`` lists one short reason per refused request."""

    scheduler: bool
    memory_locked: bool
    refused: tuple[str, ...]

    def message(self, prog: str = "arva-emulate") -> str | None:
        """The one stderr line when something was refused, else None."""
        if not self.refused:
            return None
        return f"{prog}: --realtime: not permitted ({'; '.join(self.refused)}); continuing without it"


def request_realtime(priority: int = PRIORITY) -> RealtimeResult:
    """SCHED_FIFO at ``priority`` and mlockall for this process, where permitted.

    Memory is locked with MCL_FUTURE as well only when the locked-memory limit cannot
    make later allocations fail (unlimited, or root); otherwise only the pages mapped now.
    The garbage collector's long-lived objects are frozen first, so a full collection
    has less to walk during the run.
    """
    refused = []
    scheduler = memory = False
    gc.collect()
    gc.freeze()
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        scheduler = True
    except (AttributeError, OSError) as exc:  # AttributeError: not Linux
        refused.append(f"SCHED_FIFO: {getattr(exc, 'strerror', None) or exc}")
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        flags = _MCL_CURRENT
        if soft == resource.RLIM_INFINITY or os.geteuid() == 0:
            flags |= _MCL_FUTURE
        if libc.mlockall(flags) == 0:
            memory = True
        else:
            refused.append(f"mlockall: {os.strerror(ctypes.get_errno())}")
    except (AttributeError, OSError) as exc:
        refused.append(f"mlockall: {exc}")
    return RealtimeResult(scheduler, memory, tuple(refused))
