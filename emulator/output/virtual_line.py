"""What a pyserial URL handler without a UART behind it answers for the line itself:
nothing to configure (baud rate and framing mean nothing to an in-memory line or a USB
endpoint), RTS/DTR/break accepted and ignored, the modem lines of a cable that is
plugged in (CTS, DSR and CD on, RI off), and no output queue (a write is done when it
returns). Mixed in before ``serial.SerialBase``: by the URL handlers (``arvaemu://``,
``usb://``) and by each network client's emulated UART (:mod:`emulator.output.net_ports`,
which configures its line and purges itself)."""

from __future__ import annotations

from serial.serialutil import PortNotOpenError, SerialException


class VirtualLine:
    def _reconfigure_port(self, force_update: bool = False) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    def reset_output_buffer(self) -> None:
        self._require_open()

    def _may_open(self) -> None:
        """What pyserial checks before an ``open()``, in its words."""
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")

    def _require_open(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    cts = dsr = cd = property(lambda self: True)
    ri = property(lambda self: False)
    out_waiting = property(lambda self: 0)
