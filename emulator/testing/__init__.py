"""Run ``arva-emulate`` from tests: the harness library and the ``arva`` pytest plugin.

* :class:`EmulatorProcess` starts ``arva-emulate`` with any arguments on ptys, reads its
  announcement lines (``<stream> <path>``, ``control ADDRESS``) and stops it cleanly.
* :class:`Emulator` is the handle of one started with a control channel (the fixture
  ``arva_emulator`` returns it): ``step``, ``set_transmitter``, ``fault`` ... each a
  thin call of the control request of the same name (docs/hil_testing.md).
* :class:`ControlClient` speaks the JSON-lines control protocol and keeps a transcript.
* :func:`read_lines` reads CR LF lines from a pyserial port with a deadline.
* :mod:`emulator.testing.qemu` (imported on use): firmware in the loop, a QEMU board whose
  UART0 the emulator writes into (``Board``, ``FirmwareLoop``, ``build_firmware``).

Importing this package is cheap (no numpy): pytest loads the plugin in every run.
"""

from emulator.testing.harness import (
    ControlClient,
    ControlReplyError,
    Emulator,
    EmulatorError,
    EmulatorProcess,
    process_rss_kb,
    read_lines,
)

__all__ = [
    "ControlClient",
    "ControlReplyError",
    "Emulator",
    "EmulatorError",
    "EmulatorProcess",
    "process_rss_kb",
    "read_lines",
]
