"""Streams: what the emulator sends on each port, epoch by epoch.

A stream has a rate, a label (``arva``, ``arva:2``, ``gps:rx`` ...) and renders the bytes
of epochs ``k0 .. k0 + count - 1`` (epoch k at scene time k / rate_hz). The scheduler
decides when to render and where the bytes go.
"""

from __future__ import annotations

from firmware_proto.sentences import encode_epochs

from emulator.receiver.receiver import Receiver
from emulator.scene.reader import Scene


class Stream:
    """Base class: ``render(k0, count)`` returns the bytes of those epochs, in order."""

    kind = "stream"

    def __init__(self, label: str, rate_hz: float) -> None:
        self.label = label
        self.rate_hz = rate_hz

    def render(self, k0: int, count: int) -> bytes:
        raise NotImplementedError


class ArvaStream(Stream):
    """The receiver's ``$PARVA`` (and optional ``$PARVH``) sentences."""

    kind = "arva"

    def __init__(self, scene: Scene, index: int, label: str) -> None:
        super().__init__(label, scene.rate_hz)
        if scene.receivers[index].vehicle is not None:
            # Closed loop: poses come from the vehicle (or an autopilot), epoch by epoch.
            from emulator.closed_loop.loop import ClosedLoop

            self.receiver = ClosedLoop(scene, index, record=False)
        else:
            self.receiver = Receiver(scene, index)

    def render(self, k0: int, count: int) -> bytes:
        if k0 != self.receiver.next_k:
            raise ValueError(f"{self.label}: epochs must be rendered in order ({k0} != {self.receiver.next_k})")
        batch = self.receiver.next_batch(count)
        ep = batch.epochs
        return encode_epochs(batch.k0, ep.ids, ep.d, ep.delta, ep.field)


def scene_streams(scene: Scene) -> list[Stream]:
    """Every stream the scene asks for: receivers first (the first one counts --frames),
    then the ground-truth GPS and attitude streams."""
    from emulator.truth.streams import ground_truth_streams  # imports pynmeagps: only when needed

    several = len(scene.receivers) > 1
    arva: list[Stream] = [
        ArvaStream(scene, i, f"arva:{rx.id}" if several else "arva") for i, rx in enumerate(scene.receivers)
    ]
    wants_truth = any(d.gps or d.attitude for d in (*scene.receivers, *scene.transmitters))
    return arva + (ground_truth_streams(scene) if wants_truth else [])
