"""Serves control requests (BRIEF 9) against a running emulator: the scheduler (clock,
epoch index, pause) and the :class:`~emulator.pipeline.Pipeline` (transmitters,
receiver pins, faults on demand, the step clock's :meth:`~emulator.pipeline.Pipeline.step`).

:meth:`Controller.handle` takes a parsed request and returns the reply object (for a
``step``, a :class:`StepJob` the server runs :data:`STEP_SLICE` epochs at a time). It
holds the scheduler's lock while it works, so a change lands between two epochs and
takes effect from the next epoch rendered, whose index the reply carries (``epoch``).
Errors raise :class:`~emulator.control.requests.ControlError` (or the pipeline's
:class:`InputError`, which the server names by the request's ``op``) and change nothing. What
each request does: docs/hil_testing.md, "Protocol".
"""

from __future__ import annotations

from dataclasses import asdict

from emulator.output.scheduler import STEP_DRAIN_WAIT, EpochScheduler
from emulator.pipeline import Pipeline

from emulator.control import requests as rq
from emulator.control.requests import ControlError, Request, error_reply

CLOCKS = ("real", "step")
#: Most epochs (of the first stream, with every other stream's epochs due meanwhile) a
#: ``step`` writes before the control channel serves the other clients' requests again.
#: An epoch of the default scene takes ~0.4 ms on the 2-core development machine under
#: load, so a slice is ~40 ms; a ``step`` of 1,000,000 epochs is 10,000 slices.
STEP_SLICE = 100


class Controller:
    """``clock`` is ``"step"`` or ``"real"``. ``quit`` only replies: the server ends
    the run once the reply is sent."""

    def __init__(self, scheduler: EpochScheduler, pipe: Pipeline, clock: str) -> None:
        if clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {clock!r}")
        self.scheduler = scheduler
        self.pipe = pipe
        self.clock = clock
        self.rate0 = scheduler.routes[0].stream.rate_hz
        # A stall asked for holds the stream's bytes in scene time, under both clocks: a
        # sleep would hold the scheduler (and this channel) for as long as asked.
        pipe.stall_hold = True

    def handle(self, req: Request) -> dict | StepJob:
        """The reply; for a ``step``, a :class:`StepJob` that the server runs a slice at a time."""
        if isinstance(req, rq.Step):
            return StepJob(self, req.n)
        with self.scheduler.lock:  # between two epochs
            return {"ok": True, **self._dispatch(req)}

    def _dispatch(self, req: Request) -> dict:
        sch, pipe = self.scheduler, self.pipe
        t = sch.next_epoch / self.rate0  # the next epoch's scene time (s)
        if isinstance(req, rq.Status):
            return {"epoch": sch.next_epoch, "t": t, "clock": self.clock, "paused": sch.paused,
                    "streams": {r.stream.label: r.port.path or "-" for r in sch.routes}}
        if isinstance(req, rq.Truth):
            receivers = [{"id": p.id, "position": p.position, "orientation": p.orientation} for p in pipe.receiver_poses(t)]
            transmitters = list(map(asdict, pipe.transmitter_poses(t)))
            return {"epoch": sch.next_epoch, "t": t, "receivers": receivers, "transmitters": transmitters}
        if isinstance(req, rq.Quit):
            return {}
        # The changes: each takes effect from the epoch the reply names.
        if isinstance(req, (rq.Pause, rq.Resume)):
            if self.clock != "real":
                raise ControlError(f"{req.op}: the step clock emits only on step (pause/resume are for --clock real)")
            sch.paused = isinstance(req, rq.Pause)
        elif isinstance(req, rq.SetTransmitter):
            pipe.set_transmitter(req.id, req.position, req.orientation, req.enabled)
        elif isinstance(req, rq.RemoveTransmitter):
            pipe.remove_transmitter(req.id)
        elif isinstance(req, rq.SetReceiver):
            ids = [rx.id for rx in pipe.scene.receivers]
            if req.id is not None and req.id not in ids:
                raise ControlError(f"set_receiver: no receiver {req.id} (ids: {', '.join(map(str, ids))})")
            index = 0 if req.id is None else ids.index(req.id)
            if req.path == "resume":
                pipe.release_receiver(index)
            else:
                pipe.pin_receiver(index, req.position, req.orientation)
        elif isinstance(req, rq.Fault):
            amount = {"disconnect": req.seconds, "stall": req.ms, "corrupt": req.count}[req.kind]
            pipe.fault(req.stream, req.kind, amount)  # from the stream's next epoch
        else:
            raise ControlError(f"unknown request {req!r}")  # parse_request never makes one
        return {"epoch": sch.next_epoch}


class StepJob:
    """One ``step`` request, written :data:`STEP_SLICE` epochs at a time (a
    :class:`~emulator.control.server.Sliced` request): between two slices the server
    serves the other clients, and a change one of them makes takes effect from the next
    epoch written (its reply names it). Checked when its first slice runs (after any
    step queued before it); the slices together write exactly the bytes of one
    ``Pipeline.step(n)``. Its reply, ``{"ok": true, "epoch": ...}``, comes after its last epoch."""

    op = "step"  # names the pipeline's errors in the server's replies

    def __init__(self, controller: Controller, n: int) -> None:
        self.controller = controller
        self.n = n
        self.done = 0
        self.started = False

    def advance(self) -> dict | None:
        ctl, sch = self.controller, self.controller.scheduler
        with sch.lock:  # between two epochs
            if not self.started:
                if ctl.clock != "step":
                    raise ControlError("step: the emulator runs on the real clock "
                                       "(start it with --clock step)")
                left = sch.remaining()
                if left is not None and self.n > left:
                    raise ControlError(f"step: n = {self.n} but only {left} epochs are left (--frames)")
                for r in sch.routes:
                    r.port.set_drain_wait(STEP_DRAIN_WAIT)  # a reader that keeps reading loses nothing
                self.started = True
            count = min(STEP_SLICE, self.n - self.done)
            ctl.pipe.step(count)
            self.done += count
            return {"ok": True, "epoch": sch.next_epoch} if self.done == self.n else None

    def abandon(self, why: str) -> dict:
        return error_reply(f"step: {why}: stopped after {self.done} of {self.n} epochs")
