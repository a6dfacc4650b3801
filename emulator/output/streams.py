"""Streams: what the emulator sends on each port, epoch by epoch.

A stream has a rate, a label (``arva``, ``arva:2``, ``gps:rx`` ...) and renders the bytes
of epochs ``k0 .. k0 + count - 1`` (epoch k at scene time k / rate_hz, seconds). The
scheduler decides when to render and where the bytes go. Which streams a scene has, and
what feeds them, is decided once, by :mod:`emulator.pipeline`.
"""

from __future__ import annotations

from firmware_proto.sentences import encode_epochs


class Stream:
    """Base class: ``render(k0, count)`` returns the bytes of those epochs, in order."""

    def __init__(self, label: str, rate_hz: float) -> None:
        self.label = label
        self.rate_hz = rate_hz

    def render(self, k0: int, count: int) -> bytes:
        raise NotImplementedError


class ArvaStream(Stream):
    """The receiver's ``$PARVA`` (and optional ``$PARVH``) sentences from ``source``, a
    :class:`~emulator.receiver.receiver.Receiver` or a closed loop: its ``next_batch(count)``
    gives the channel-selected epochs ``next_k ..`` strictly in order (an ``EpochBatch``), and
    its ``receiver.channels`` how many it selects."""

    def __init__(self, label: str, rate_hz: float, source) -> None:
        super().__init__(label, rate_hz)
        self.receiver = source

    def render(self, k0: int, count: int) -> bytes:
        if k0 != self.receiver.next_k:
            raise ValueError(f"{self.label}: epochs must be rendered in order ({k0} != {self.receiver.next_k})")
        batch = self.receiver.next_batch(count)
        ep = batch.epochs  # receiver.model.Epochs: ids, d, delta (N, channels), field or None
        return encode_epochs(batch.k0, ep.ids, ep.d, ep.delta, ep.field)

    def close(self) -> None:
        close = getattr(self.receiver, "close", None)
        if close is not None:
            close()

