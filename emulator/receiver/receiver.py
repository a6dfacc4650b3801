"""An emulated receiver: the scene's poses at each epoch time, the model, the effects
pipeline and channel selection, producing epochs in order."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from emulator.receiver.noise import NoiseEffect
from emulator.receiver.pulses import PulseEffect
from emulator.receiver.quantize import QuantizeEffect
from emulator.receiver.model import ZONE_OUTER, Epochs, Measurement, measure, select_channels
from emulator.frames.trajectory import Trajectory
from emulator.scene.types import Scene, Transmitter


@dataclass
class EpochBatch:
    """Epochs ``k0 .. k0 + count - 1`` at scene times ``t`` (s), channel-selected."""

    k0: int
    t: np.ndarray
    epochs: Epochs


class Receiver:
    """Produces the receiver's epochs for a scene, in order.

    Epoch k uses the scene state at t_k = k / rate_hz (BRIEF 3 step 7). Effects that act
    on the raw measurement (pulses) run before channel selection, display ones (quantize)
    after it; a disabled effect is None. Effects with random draws consume their
    streams in epoch order, so call :meth:`next_batch` sequentially; the batch size
    does not change the output.
    """

    def __init__(self, scene: Scene, index: int = 0, want_field: bool | None = None) -> None:
        self.scene = scene
        self.spec = scene.receivers[index]
        self.channels = self.spec.channels
        # The field rides along for $PARVH, or when a closed-loop controller needs it.
        self.want_field = scene.effects.research_sentences if want_field is None else want_field
        fx = scene.effects
        # Each receiver draws noise from its own stream of the scene seed; pulse trains
        # belong to the transmitters, so every receiver hears the same ones.
        self.noise = NoiseEffect(scene.seed, index) if fx.noise else None
        # The receiver's class and constants (its profile and the scene's [model]).
        self.model = scene.receiver_model(index)
        display = self.spec.display or fx.quantize  # the profile's display unless the scene sets one
        self.quantize = QuantizeEffect(display) if display else None
        self.next_k = 0
        #: Where the receiver is: the scene trajectory, or a pose pinned by :meth:`pin`.
        self.trajectory: Trajectory = self.spec.trajectory
        self.set_transmitters(scene.transmitters)

    def set_transmitters(self, transmitters: Sequence[Transmitter]) -> None:
        """Hear these transmitters from the next epoch on (ids distinct; any order).

        The scene's transmitters at construction; a control channel may add, move,
        silence (leave out) or remove them between epochs. Pulse trains depend only on
        the ids and the seed, so a transmitter keeps its timing across changes.
        """
        txs = tuple(sorted(transmitters, key=lambda tx: tx.id))
        self.transmitters = txs
        self.ids = np.array([tx.id for tx in txs], dtype=np.int64)
        fx = self.scene.effects
        self.pulses = PulseEffect(fx.pulses, self.ids, self.scene.seed) if fx.pulses and len(self.ids) else None
        self._static_tx = all(tx.trajectory.is_static for tx in txs)
        if self._static_tx:  # (0, 3), (0, 4) without transmitters: the model gives empty epochs
            self._tx_pos = np.array([tx.trajectory.positions[0] for tx in txs]).reshape(-1, 3)
            self._tx_quat = np.array([tx.trajectory.orientations[0] for tx in txs]).reshape(-1, 4)

    def pin(self, trajectory: Trajectory | None) -> None:
        """Take poses from ``trajectory`` from the next epoch on (e.g. a static pose a
        control channel pinned); None hands the receiver back to its scene path."""
        self.trajectory = self.spec.trajectory if trajectory is None else trajectory

    def next_batch(self, count: int) -> EpochBatch:
        k0 = self.next_k
        t = (k0 + np.arange(count, dtype=np.float64)) / self.scene.rate_hz
        self.next_k += count
        return EpochBatch(k0, t, self.evaluate(t))

    def evaluate(self, t: np.ndarray) -> Epochs:
        """Channel-selected epochs at scene times ``t`` (draws noise if enabled)."""
        return self.evaluate_poses(t, *self.trajectory.at(t))

    def evaluate_poses(self, t: np.ndarray, rx_pos, rx_quat) -> Epochs:
        """Like :meth:`evaluate`, with the receiver poses (N, 3), (N, 4) given by the
        caller (a vehicle in closed loop, an autopilot) instead of the scene trajectory."""
        n, m = t.size, len(self.ids)
        if self._static_tx:
            tx_pos, tx_quat = self._tx_pos, self._tx_quat
        else:
            poses = [tx.trajectory.at(t) for tx in self.transmitters]
            tx_pos = np.stack([p for p, _ in poses], axis=1)
            tx_quat = np.stack([q for _, q in poses], axis=1)
        noise = self.noise.draw(n, m) if self.noise is not None else None
        meas = measure(rx_pos, rx_quat, tx_pos, tx_quat, self.model, noise, self.want_field)
        if self.pulses is not None:  # acts on the raw measurement, before channel selection
            self._apply_pulses(t, meas)
        epochs = select_channels(meas, self.ids, self.channels)
        if self.quantize is not None:  # the display, after it
            epochs.d, epochs.delta = self.quantize.apply(epochs.d, epochs.delta, epochs.ids < 0)
        return epochs

    def _apply_pulses(self, t: np.ndarray, meas: Measurement) -> None:
        """Silence transmitters with no unhidden pulse ending in (t - 1/rate, t]."""
        present = meas.zone != ZONE_OUTER
        # Larger is stronger: d orders transmitters as their field at the receiver does.
        strength = -meas.d.astype(np.float64)
        heard = self.pulses.reported(t - 1.0 / self.scene.rate_hz, t, strength, present)
        silent = present & ~heard
        meas.zone[silent] = ZONE_OUTER
        meas.d[silent] = -1
        meas.delta[silent] = -1
