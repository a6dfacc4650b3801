"""Test helper: run a command's ``main(argv)`` in a fresh interpreter where one package
cannot be imported, as on a machine without that extra."""

from __future__ import annotations

import subprocess
import sys


def run_without(package: str, main: str, argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    """``main`` is ``"module:function"``; returns the finished process (text output)."""
    module, _, func = main.partition(":")
    code = f"import sys; sys.modules[{package!r}] = None\nfrom {module} import {func}\nsys.exit({func}({argv!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
