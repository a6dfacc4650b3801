"""Starting one of our own modules as a child process (``sys.executable -m PACKAGE.MODULE``).

Used by the emulator (the ``--realtime-workers`` keeper) and the bench (the fit's worker);
it lives in ``emulator`` so both can import it (bench -> emulator, never back).
"""

from __future__ import annotations

import os
from pathlib import Path

#: The directory holding ``emulator/``, ``bench/`` and ``firmware_proto/``.
SOURCE_ROOT = str(Path(__file__).resolve().parents[1])


def module_env() -> dict[str, str]:
    """This process's environment with :data:`SOURCE_ROOT` first on ``PYTHONPATH``, so a
    child started with ``sys.executable -m`` imports this source tree, installed or not."""
    env = dict(os.environ)
    env["PYTHONPATH"] = SOURCE_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env
