"""Starting one of our own modules as a child process (``python -P -m PACKAGE.MODULE``).

Used by the ``--realtime-workers`` keeper, the HIL harness and the fit's worker; it lives
in ``emulator`` so all can import it (bench -> emulator, never back).

The child is isolated from the caller's working directory: plain ``python -m`` puts the
working directory first on ``sys.path``, so a user's repository with its own top-level
``emulator/`` or ``bench/`` package would hide ours (``No module named emulator.cli``).
``-P`` (Python >= 3.11) leaves it out; :func:`module_env` puts this source tree first on
``PYTHONPATH`` instead, so the child imports the same code as its parent, installed or not.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Mapping
from pathlib import Path

#: The directory holding ``emulator/``, ``bench/`` and ``firmware_proto/``.
SOURCE_ROOT = str(Path(__file__).resolve().parents[1])


def module_command(module: str, *args: str) -> list[str]:
    """The command line starting ``module`` (``PACKAGE.MODULE``) with ``args`` in this
    interpreter, with nothing of the working directory on its ``sys.path``."""
    return [sys.executable, "-P", "-m", module, *args]


def module_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) with :data:`SOURCE_ROOT` first on
    ``PYTHONPATH``, so a child started by :func:`module_command` imports this source tree."""
    env = dict(os.environ if base is None else base)
    env["PYTHONPATH"] = SOURCE_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def end_with_parent() -> None:
    """``preexec_fn`` of a child that must not outlive the test that started it: SIGTERM
    it when the starting process ends, even by SIGKILL (a CI timeout), with Linux's
    ``PR_SET_PDEATHSIG``; an orphaned emulator or QEMU would otherwise keep its ptys (a
    logger reopening a path steals the next run's bytes) or spin a core. Linux ties this
    to the starting *thread*: start from a thread that outlives the child (the test's own,
    as the fixtures do). Elsewhere a no-op."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
