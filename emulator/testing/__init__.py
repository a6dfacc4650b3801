"""Run ``arva-emulate`` from tests: the harness library (:mod:`emulator.testing.harness`:
:class:`EmulatorProcess`, :class:`Emulator`, :class:`ControlClient`, :func:`read_lines`),
firmware in the loop (:mod:`emulator.testing.qemu`, imported on use) and the ``arva``
pytest plugin (docs/hil_testing.md). Importing this package is cheap (no numpy): pytest
loads the plugin in every run.
"""

from emulator.testing.harness import (
    ControlClient, ControlReplyError, Emulator, EmulatorError, EmulatorProcess, process_rss_kb, read_lines,
)

__all__ = [  # the harness library's public names (re-exported)
    "ControlClient", "ControlReplyError", "Emulator", "EmulatorError", "EmulatorProcess", "process_rss_kb",
    "read_lines",
]
