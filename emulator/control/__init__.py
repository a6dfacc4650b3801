"""The live control channel of ``arva-emulate --control`` (BRIEF 9, docs/hil_testing.md).

* :mod:`~emulator.control.requests`: the JSON-lines requests as validated structs (msgspec).
* :mod:`~emulator.control.server`: the unix / TCP socket server (several clients).
* :mod:`~emulator.control.controller`: serves requests against the scheduler and the
  :class:`~emulator.pipeline.Pipeline` (changes between epochs, the step clock).
* :mod:`~emulator.control.runtime`: the command-line options, ``--capture`` (copies of
  the streams' bytes) and the wiring into ``arva-emulate``.
"""
