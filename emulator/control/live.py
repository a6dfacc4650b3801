"""The live scene: transmitters and receiver poses as the control channel changed them.

Rendering is sequential, so a change needs no history: it is pushed into the streams
(receivers' transmitter sets, receivers' and ground-truth streams' trajectories) and
every epoch rendered after it uses it. Poses are ENU metres and unit quaternions
``[w, x, y, z]`` (BRIEF 2).

* ``set_transmitter``: a position and/or orientation pins the transmitter at that pose
  (a pose not given is taken from where it would be at the next epoch); ``enabled``
  false silences it: it leaves every receiver's channel selection, so its slot frees as
  a real receiver's does; true brings it back. An unknown id adds a transmitter (it has
  no ground-truth streams: those are fixed when the emulator starts).
* ``remove_transmitter``: it is gone from every receiver. Its GPS / attitude streams, if
  the scene gave it any, keep reporting the pose it had.
* ``set_receiver``: pins a receiver's pose (its ground-truth streams follow); ``path:
  resume`` hands it back to its scene path, at the scene time of the next epoch. A
  receiver on a vehicle (closed loop) cannot be pinned: its pose comes from the vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from emulator.closed_loop.loop import ClosedLoop
from emulator.frames.trajectory import Trajectory
from emulator.output.streams import ArvaStream, Stream
from emulator.receiver.receiver import Receiver
from emulator.scene.reader import Scene

from emulator.control.requests import ControlError, SetReceiver, SetTransmitter


@dataclass
class TransmitterState:
    id: int
    trajectory: Trajectory
    enabled: bool = True


@dataclass(frozen=True)
class DevicePose:
    """One device's pose at a scene time (the ``truth`` reply)."""

    id: int
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    enabled: bool | None = None

    def as_dict(self) -> dict:
        out = {"id": self.id, "position": list(self.position), "orientation": list(self.orientation)}
        if self.enabled is not None:
            out["enabled"] = self.enabled
        return out


class LiveScene:
    """The scene as changed live; ``streams`` are the emulator's streams (receivers first)."""

    def __init__(self, scene: Scene, streams: list[Stream]) -> None:
        self.scene = scene
        self.transmitters: dict[int, TransmitterState] = {
            tx.id: TransmitterState(tx.id, tx.trajectory) for tx in scene.transmitters
        }
        arva = [s for s in streams if isinstance(s, ArvaStream)]
        self.receivers = list(zip(scene.receivers, arva))
        self.pinned: dict[int, Trajectory] = {}
        self.truth_streams = [s for s in streams if getattr(s, "carrier", None) is not None]

    # --- queries ------------------------------------------------------------------------

    def receiver_ids(self) -> list[int]:
        return [spec.id for spec, _ in self.receivers]

    def truth(self, t: float) -> tuple[list[DevicePose], list[DevicePose]]:
        """Receivers' and transmitters' poses at scene time ``t``."""
        rxs = [DevicePose(spec.id, *self._rx_pose(spec.id, stream, t)) for spec, stream in self.receivers]
        txs = [
            DevicePose(tx.id, *_pose(tx.trajectory, t), enabled=tx.enabled)
            for tx in sorted(self.transmitters.values(), key=lambda s: s.id)
        ]
        return rxs, txs

    def _rx_pose(self, rx_id: int, stream: ArvaStream, t: float):
        engine = stream.receiver
        if isinstance(engine, ClosedLoop):
            uav = engine.uav
            if uav is not None:  # where the vehicle is now, i.e. at the next epoch
                return tuple(map(float, uav.position)), tuple(map(float, uav.orientation))
            return _pose(engine.receiver.trajectory, t)
        return _pose(engine.trajectory, t)

    # --- changes ------------------------------------------------------------------------

    def set_transmitter(self, req: SetTransmitter, t: float) -> None:
        state = self.transmitters.get(req.id)
        if state is None:
            if req.position is None:
                raise ControlError(f"set_transmitter: id {req.id} is new: a position is required to add it")
            orientation = req.orientation if req.orientation is not None else (1.0, 0.0, 0.0, 0.0)
            state = TransmitterState(req.id, Trajectory.static(req.position, orientation))
            state.enabled = True if req.enabled is None else req.enabled
            self.transmitters[req.id] = state
        else:
            if req.position is not None or req.orientation is not None:
                pos, quat = _pose(state.trajectory, t)
                state.trajectory = Trajectory.static(
                    req.position if req.position is not None else pos,
                    req.orientation if req.orientation is not None else quat,
                )
            if req.enabled is not None:
                state.enabled = req.enabled
        self._push_transmitters()

    def remove_transmitter(self, tx_id: int) -> None:
        if tx_id not in self.transmitters:
            known = ", ".join(str(i) for i in sorted(self.transmitters)) or "none"
            raise ControlError(f"remove_transmitter: no transmitter {tx_id} (ids: {known})")
        del self.transmitters[tx_id]
        self._push_transmitters()

    def set_receiver(self, req: SetReceiver, t: float) -> int:
        """Apply; return the receiver's id."""
        ids = self.receiver_ids()
        if req.id is None:
            spec, stream = self.receivers[0]
        elif req.id in ids:
            spec, stream = self.receivers[ids.index(req.id)]
        else:
            raise ControlError(f"set_receiver: no receiver {req.id} (ids: {', '.join(map(str, ids))})")
        engine = stream.receiver
        if not isinstance(engine, Receiver):
            raise ControlError(f"set_receiver: receiver {spec.id} rides a vehicle (closed loop): its pose comes from the vehicle")
        if req.resume_path:
            self.pinned.pop(spec.id, None)
            trajectory = spec.trajectory
        else:
            pos, quat = _pose(engine.trajectory, t)
            trajectory = Trajectory.static(
                req.position if req.position is not None else pos,
                req.orientation if req.orientation is not None else quat,
            )
            self.pinned[spec.id] = trajectory
        engine.trajectory = trajectory
        for s in self.truth_streams:
            if s.carrier == ("rx", spec.id):
                s.trajectory = trajectory
        return spec.id

    def _push_transmitters(self) -> None:
        heard = sorted((s for s in self.transmitters.values() if s.enabled), key=lambda s: s.id)
        ids = np.array([s.id for s in heard], dtype=np.int64)
        trajectories = [s.trajectory for s in heard]
        for _, stream in self.receivers:
            engine = stream.receiver
            receiver = engine.receiver if isinstance(engine, ClosedLoop) else engine
            receiver.set_transmitters(ids, trajectories)
        for s in self.truth_streams:
            kind, dev_id = s.carrier
            if kind == "tx" and dev_id in self.transmitters:
                s.trajectory = self.transmitters[dev_id].trajectory


def _pose(trajectory: Trajectory, t: float):
    pos, quat = trajectory.at(np.array([t]))
    return tuple(float(v) for v in pos[0]), tuple(float(v) for v in quat[0])
