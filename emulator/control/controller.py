"""Serves control requests (BRIEF 9) against a running emulator: the scheduler (clock,
epochs, pause), the live scene (transmitters, receivers) and the streams' fault ports.

:meth:`Controller.handle` takes a parsed request and returns the reply object. It holds
the scheduler's lock while it works, so a change lands between two epochs and takes
effect from the next epoch rendered, whose index the reply carries (``epoch``). Errors
are :class:`~emulator.control.requests.ControlError` and change nothing: every check is
made before the first change.
"""

from __future__ import annotations

from emulator.output.scheduler import EpochScheduler

from emulator.control.faults import ControlledPort
from emulator.control.live import LiveScene
from emulator.control.requests import (
    ControlError,
    Fault,
    Pause,
    Quit,
    RemoveTransmitter,
    Request,
    Resume,
    SetReceiver,
    SetTransmitter,
    Status,
    Step,
    Truth,
)

CLOCKS = ("real", "step")


class Controller:
    """``clock`` is ``"step"`` or ``"real"``; ``ports`` maps stream label -> its
    :class:`ControlledPort`. ``quit`` only replies: the server ends the run once the
    reply is sent (its ``on_quit``)."""

    def __init__(
        self,
        scheduler: EpochScheduler,
        live: LiveScene,
        clock: str,
        ports: dict[str, ControlledPort],
    ) -> None:
        if clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {clock!r}")
        self.scheduler = scheduler
        self.live = live
        self.clock = clock
        self.ports = ports
        self.rate0 = scheduler.routes[0].stream.rate_hz

    def handle(self, req: Request) -> dict:
        with self.scheduler.lock:
            return {"ok": True, **self._dispatch(req)}

    def _epoch(self) -> dict:
        return {"epoch": self.scheduler.next_epoch}

    def _t(self) -> float:
        return self.scheduler.next_epoch / self.rate0

    def _dispatch(self, req: Request) -> dict:
        sch = self.scheduler
        if isinstance(req, Status):
            return {
                "epoch": sch.next_epoch,
                "t": self._t(),
                "clock": self.clock,
                "paused": sch.paused,
                "streams": {r.stream.label: r.port.path or "-" for r in sch.routes},
            }
        if isinstance(req, Step):
            if self.clock != "step":
                raise ControlError("step: the emulator runs on the real clock (start it with --clock step)")
            left = sch.remaining()
            if left is not None and req.n > left:
                raise ControlError(f"step: n = {req.n} but only {left} epochs are left (--frames)")
            sch.step(req.n)
            return self._epoch()
        if isinstance(req, (Pause, Resume)):
            if self.clock != "real":
                raise ControlError(f"{req.op}: the step clock emits only on step (pause/resume are for --clock real)")
            sch.pause() if isinstance(req, Pause) else sch.resume()
            return self._epoch()
        if isinstance(req, SetTransmitter):
            self.live.set_transmitter(req, self._t())
            return self._epoch()
        if isinstance(req, RemoveTransmitter):
            self.live.remove_transmitter(req.id)
            return self._epoch()
        if isinstance(req, SetReceiver):
            self.live.set_receiver(req, self._t())
            return self._epoch()
        if isinstance(req, Fault):
            port = self.ports.get(req.stream)
            if port is None:
                raise ControlError(f"fault: no stream {req.stream!r} (streams: {', '.join(self.ports)})")
            if req.kind == "disconnect":
                port.disconnect_for(req.seconds)
            elif req.kind == "stall":
                port.stall_for(req.ms)
            else:
                port.corrupt_next(req.count)
            sch.fast_batch = 1  # faults are timed per epoch: never batch epochs again
            return self._epoch()
        if isinstance(req, Truth):
            rxs, txs = self.live.truth(self._t())
            return {
                **self._epoch(),
                "t": self._t(),
                "receivers": [p.as_dict() for p in rxs],
                "transmitters": [p.as_dict() for p in txs],
            }
        if isinstance(req, Quit):
            return {}
        raise ControlError(f"unknown request {req!r}")  # parse_request never makes one
