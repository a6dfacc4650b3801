"""The emulator pipeline: the one path from a scene to bytes on ports, for every door.

Scene -> poses -> model -> measurement effects -> channel selection -> display ->
sentences -> link faults -> ports; the diagram, the stream order (which seeds each
stream's link faults), the doors and the clocks are in docs/architecture.md "The
pipeline". ``arva-emulate``, ``arvaemu://`` and the control channel all build a
:class:`Pipeline`, so the same scene gives the same bytes through every door; changes
between epochs (:meth:`Pipeline.set_transmitter`, :meth:`Pipeline.pin_receiver`,
:meth:`Pipeline.fault`, ...) take effect from the next epoch rendered.

Times are scene seconds; positions world ENU metres; quaternions [w, x, y, z] body to
world (BRIEF 2).
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, replace

import numpy as np

from firmware_proto.errors import InputError
from firmware_proto.sentences import MAX_ID

from emulator.closed_loop.loop import ClosedLoop
from emulator.frames.rotation import normalize_quaternions
from emulator.frames.trajectory import IDENTITY, Trajectory
from emulator.output.link_faults import FaultyPort, LinkFaultConfig
from emulator.output.ports import Port
from emulator.output.scheduler import Route, SceneClock, epochs_before
from emulator.output.streams import ArvaStream, Stream
from emulator.receiver.receiver import Receiver
from emulator.scene.types import Scene, Transmitter, arva_labels
from emulator.schema import Int, SchemaError, Vector3, Vector4, convert, join_key
from emulator.truth.streams import TruthCarrier, ground_truth_carriers, ground_truth_stream


@dataclass(frozen=True)
class StreamInfo:
    """One stream of a scene, before anything is built.

    ``index`` is its position in :func:`stream_layout` (it seeds the stream's link
    faults); ``receiver`` the receiver index of an ``arva`` stream; ``carrier`` the
    ground-truth device of a ``gps`` / ``attitude`` stream.
    """

    index: int
    label: str
    kind: str
    rate_hz: float
    receiver: int | None = None
    carrier: TruthCarrier | None = None


@dataclass(frozen=True)
class EpochRef:
    """Epoch ``k`` of stream ``label`` at scene time ``t`` (s)."""

    t: float
    label: str
    k: int


def stream_layout(scene: Scene) -> tuple[StreamInfo, ...]:
    """Every stream the scene asks for, in order: receivers, then ground truth."""
    out = [StreamInfo(i, label, "arva", scene.rate_hz, receiver=i) for i, label in enumerate(arva_labels(scene.receivers))]
    gt = scene.ground_truth
    for c in ground_truth_carriers(scene):
        rate = gt.gps_rate_hz if c.kind == "gps" else gt.attitude_rate_hz
        out.append(StreamInfo(len(out), c.label, c.kind, rate, carrier=c))
    return tuple(out)


def build_stream(scene: Scene, info: StreamInfo) -> Stream:
    """The stream ``info`` describes (see :func:`stream_layout`). A receiver's epochs come
    from its vehicle's closed loop (or the autopilot it rides on), else from a
    :class:`Receiver` on its scene trajectory."""
    if info.kind != "arva":
        return ground_truth_stream(scene, info.carrier)
    i = info.receiver
    source = Receiver(scene, i) if scene.receivers[i].vehicle is None else ClosedLoop(scene, i, record=False)
    return ArvaStream(info.label, info.rate_hz, source)


def scene_streams(scene: Scene) -> list[Stream]:
    """Every stream of the scene, built, in :func:`stream_layout` order."""
    return [build_stream(scene, info) for info in stream_layout(scene)]


@dataclass(frozen=True)
class Pose:
    """A device's ground truth: ``position`` ENU metres, ``orientation`` [w, x, y, z]
    body to world, ``enabled`` (transmitters: not silenced)."""

    id: int
    position: list[float]
    orientation: list[float]
    enabled: bool = True


def _pose_at(trajectory: Trajectory, t: float) -> tuple[list[float], list[float]]:
    pos, quat = trajectory.at(np.array([t]))
    return [float(v) for v in pos[0]], [float(v) for v in quat[0]]


class Pipeline(AbstractContextManager):
    """A scene's streams, bound to ports, written epoch by epoch.

    ``labels`` picks the streams to build (default: all of them); the others are not
    built at all (no receiver, no RNG). Typical use::

        pipe = Pipeline(scene)
        routes = pipe.bind({label: port, ...}, speed=0)
        EpochScheduler(routes, speed=0, scene_clock=pipe.clock).run()   # or pipe.step(n)
    """

    def __init__(self, scene: Scene, labels: Sequence[str] | None = None) -> None:
        self.scene = scene
        self.layout = stream_layout(scene)
        known = [info.label for info in self.layout]
        for label in labels or ():
            if label not in known:
                raise InputError(f"no stream {label!r} in this scene (streams: {', '.join(known)})")
        self.infos: dict[str, StreamInfo] = {i.label: i for i in self.layout if labels is None or i.label in labels}
        self.streams: dict[str, Stream] = {label: build_stream(scene, info) for label, info in self.infos.items()}
        self.clock = SceneClock()
        self.routes: list[Route] = []
        self.speed = 1.0
        #: The transmitters every receiver hears (control-channel changes included),
        #: and which of them are silenced.
        self.transmitters: dict[int, Transmitter] = {tx.id: tx for tx in scene.transmitters}
        self.silenced: set[int] = set()
        #: Stalls asked for hold bytes in scene time instead of sleeping (the step clock).
        self.stall_hold = False

    @property
    def labels(self) -> list[str]:
        return list(self.streams)

    # -- ports ------------------------------------------------------------------------
    def bind(self, ports: Mapping[str, Port], speed: float = 1.0) -> list[Route]:
        """Bind every built stream to its port (wrapped in the scene's link faults where
        they apply); the routes come back in stream order."""
        missing = [label for label in self.streams if label not in ports]
        if missing:
            raise InputError(f"no port for stream(s) {', '.join(missing)}")
        self.speed = speed
        faults, only = self.scene.effects.link_faults, self.scene.effects.link_fault_streams
        self.routes = []
        for label, stream in self.streams.items():
            port = ports[label]
            if faults is not None and (not only or label in only):
                port = self._faulty(label, port, faults)
            self.routes.append(Route(stream, port))
        return self.routes

    def _faulty(self, label: str, port: Port, config: LinkFaultConfig) -> FaultyPort:
        """``port`` with ``config``'s link faults, seeded by stream ``label``'s index. Stalls
        and split gaps are real pauses in real time; as fast as possible (``speed == 0``)
        they cost nothing (bytes still split, stall counters still count)."""
        sleep = time.sleep if self.speed > 0 else (lambda _s: None)
        index = self.infos[label].index
        return FaultyPort(port, config, self.scene.seed, stream=index, sleep=sleep, clock=self.clock)

    @property
    def fast_batch(self) -> int | None:
        """Epochs per batch as fast as possible: one when outages are scheduled (so they
        land on the right epochs while the other streams interleave), else the default."""
        lf = self.scene.effects.link_faults
        return 1 if lf is not None and lf.disconnect_every_s > 0 else None

    def route(self, label: str) -> Route:
        for r in self.routes:
            if r.stream.label == label:
                return r
        raise InputError(f"no stream {label!r} (streams: {', '.join(r.stream.label for r in self.routes)})")

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        """Close every bound port and every pose source (MAVLink links)."""
        for r in self.routes:
            r.port.close()
        self.close_sources()

    def close_sources(self) -> None:
        """Close the pose sources (MAVLink links) of closed-loop receivers."""
        for s in self.streams.values():
            if isinstance(s, ArvaStream):
                s.close()

    # -- epochs in scene-time order ---------------------------------------------------
    def upcoming(self) -> Iterator[EpochRef]:
        """The epochs still to write, all streams merged in scene-time order (ties: stream
        order), without writing anything. Endless unless every route has an end."""
        heap = [(r.t_next, i, r.next_k) for i, r in enumerate(self.routes) if not r.done]
        heapq.heapify(heap)
        while heap:
            t, i, k = heapq.heappop(heap)
            r = self.routes[i]
            yield EpochRef(t, r.stream.label, k)
            k += 1
            if r.end_k is None or k < r.end_k:
                heapq.heappush(heap, (k / r.stream.rate_hz, i, k))

    @property
    def epoch(self) -> int:
        """Index of the first stream's next epoch."""
        return self.routes[0].next_k if self.routes else 0

    def step(self, n: int = 1) -> int:
        """Write the first stream's next ``n`` epochs and every other stream's epochs due
        before the scene time that ends them (t < (epoch + n) / rate), one epoch at a
        time in scene-time order; return :attr:`epoch` after them."""
        if n < 0:
            raise InputError(f"step: n must be >= 0, got {n}")
        if not self.routes:
            raise InputError("step: no stream is bound to a port")
        first = self.routes[0]
        end = first.next_k + n
        t_end = end / first.stream.rate_hz
        for ref in self.upcoming():
            r = self.route(ref.label)
            if ref.k < epochs_before(end, r.stream.rate_hz, first.stream.rate_hz):
                r.send(1, self.clock)
            elif ref.t > t_end + 1e-9:
                break
        return self.epoch

    # -- changes between epochs -------------------------------------------------------
    def set_transmitter(self, tx_id: int, position: Sequence[float] | None = None,
                        orientation: Sequence[float] | None = None, enabled: bool | None = None) -> None:
        """Move, turn, silence or re-enable transmitter ``tx_id``; an unknown id adds one
        (``position`` required). Takes effect from the next epoch rendered.

        A position or orientation given holds the transmitter there (a scene path stops);
        a field not given keeps its value at the next epoch's time. A silenced transmitter
        is left out of every receiver's evaluation, so its slot frees. Its ground-truth
        streams (``gps:tx<id>`` ...) follow the new pose.
        """
        _checked(tx_id, Int(0, MAX_ID), "set_transmitter.id")
        _checked(enabled, bool | None, "set_transmitter.enabled")
        old = self.transmitters.get(tx_id)
        if old is None and position is None:
            raise InputError(f"set_transmitter: transmitter {tx_id} is new: position required")
        pos = None if position is None else _vector(position, "position")
        quat = None if orientation is None else _quaternion(orientation)
        if pos is not None or quat is not None:
            if old is not None:
                cur_p, cur_q = old.trajectory.at(np.array([self._t_next()]))
                pos = cur_p[0] if pos is None else pos
                quat = cur_q[0] if quat is None else quat
            trajectory = Trajectory.static(pos, IDENTITY if quat is None else quat)
            new = Transmitter(tx_id, trajectory) if old is None else replace(old, trajectory=trajectory)
            self.transmitters[tx_id] = new
            for label, info in self.infos.items():
                dev = info.carrier.device if info.carrier is not None else None
                if isinstance(dev, Transmitter) and dev.id == tx_id:
                    self.streams[label].trajectory = trajectory
        if enabled is not None:
            (self.silenced.discard if enabled else self.silenced.add)(tx_id)
        self._push_transmitters()

    def remove_transmitter(self, tx_id: int) -> None:
        if tx_id not in self.transmitters:
            known = ", ".join(map(str, sorted(self.transmitters))) or "none"
            raise InputError(f"remove_transmitter: no transmitter {tx_id} (ids: {known})")
        del self.transmitters[tx_id]
        self.silenced.discard(tx_id)
        self._push_transmitters()

    def pin_receiver(self, index: int = 0, position: Sequence[float] | None = None,
                     orientation: Sequence[float] | None = None) -> None:
        """Hold receiver ``index`` at a pose (fields not given keep their current value)
        from the next epoch on; its ground-truth streams follow. A vehicle-borne receiver
        cannot be pinned (its pose is the closed loop's)."""
        rx = self._receiver(index)
        t = np.array([self._t_next()])
        cur_p, cur_q = rx.trajectory.at(t)
        pos = cur_p[0] if position is None else _vector(position, "position")
        quat = cur_q[0] if orientation is None else _quaternion(orientation)
        self._move_receiver(index, rx, Trajectory.static(pos, quat))

    def release_receiver(self, index: int = 0) -> None:
        """Hand receiver ``index`` back to its scene path."""
        self._move_receiver(index, self._receiver(index), None)

    def fault(self, label: str, kind: str, amount: float) -> None:
        """Inject a fault on stream ``label``'s port, starting with its next epoch (at that
        epoch's scene time; see :meth:`~emulator.output.link_faults.FaultyPort.inject`):
        ``disconnect`` for ``amount`` scene seconds, ``stall`` of ``amount`` ms, ``corrupt``
        the next ``amount`` bytes. A port without link faults gets a fault-free wrapper first."""
        r = self.route(label)
        self.clock.t = r.t_next
        if not isinstance(r.port, FaultyPort):
            r.port = self._faulty(label, r.port, LinkFaultConfig())
        r.port.stall_hold = self.stall_hold
        r.port.inject(kind, amount)

    # -- ground truth -------------------------------------------------------------------
    def receiver_poses(self, t: float) -> list[Pose]:
        """Each receiver stream's pose at scene time ``t``: the scene path or a pin, the
        simulated vehicle's, or the autopilot's (MAVLink)."""
        out = []
        for label, info in self.infos.items():  # the built streams, in layout order
            if info.kind == "arva":
                src = self.streams[label].receiver
                pos, quat = src.current_pose() if isinstance(src, ClosedLoop) else _pose_at(src.trajectory, t)
                out.append(Pose(self.scene.receivers[info.receiver].id, pos, quat))
        return out

    def transmitter_poses(self, t: float) -> list[Pose]:
        """Every transmitter's pose at scene time ``t``, by id, with ``enabled``."""
        return [Pose(tx_id, *_pose_at(tx.trajectory, t), enabled=tx_id not in self.silenced)
                for tx_id, tx in sorted(self.transmitters.items())]

    # -- internals ----------------------------------------------------------------------
    def _t_next(self) -> float:
        return self.routes[0].t_next if self.routes else 0.0

    def _receivers(self) -> list[Receiver]:
        sources = [s.receiver for s in self.streams.values() if isinstance(s, ArvaStream)]
        return [src.receiver if isinstance(src, ClosedLoop) else src for src in sources]

    def _push_transmitters(self) -> None:
        heard = [tx for tx_id, tx in self.transmitters.items() if tx_id not in self.silenced]
        for rx in self._receivers():
            rx.set_transmitters(heard)

    def _receiver(self, index: int) -> Receiver:
        if not 0 <= index < len(self.scene.receivers):
            raise InputError(f"no receiver index {index} (the scene has {len(self.scene.receivers)})")
        label = self.layout[index].label
        stream = self.streams.get(label)
        if stream is None:
            raise InputError(f"receiver {self.scene.receivers[index].id}: its stream {label!r} is not built here")
        if isinstance(stream.receiver, ClosedLoop):
            raise InputError(f"receiver {self.scene.receivers[index].id} rides a vehicle: its pose cannot be pinned")
        return stream.receiver

    def _move_receiver(self, index: int, rx: Receiver, trajectory: Trajectory | None) -> None:
        rx.pin(trajectory)
        spec = self.scene.receivers[index]
        for label, info in self.infos.items():
            if info.carrier is not None and info.carrier.device is spec:
                self.streams[label].trajectory = rx.trajectory


def _checked(value, type_, what: str):
    """``value`` by the rule the control requests (and scenes) apply to it (:mod:`emulator.schema`)."""
    try:
        return convert(value.tolist() if isinstance(value, np.ndarray) else value, type_)
    except SchemaError as exc:
        raise InputError(f"{join_key(what, exc.key)}: {exc.reason}") from None


def _vector(value: Sequence[float], what: str) -> np.ndarray:
    return np.array(_checked(value, Vector3, what))


def _quaternion(value: Sequence[float]) -> np.ndarray:
    return normalize_quaternions(_checked(value, Vector4, "orientation"), "orientation")  # or PoseError
