"""The pipeline's control surface (what a control channel drives): stepping in scene-time
order, changing transmitters and receiver poses between epochs, faults on demand."""

import pytest
from scene_builders import one_tx

from emulator.output.ports import BufferPort
from emulator.pipeline import EpochRef, Pipeline
from emulator.receiver.model import measure_one
from emulator.scene.reader import loads_scene
from emulator.testing.scene_toml import dumps
from firmware_proto.errors import InputError
from firmware_proto.sentences import encode_parva

ONE = dumps(one_tx(channels=2))
TRUTH = (
    "spec = 1\n[origin]\nlat = 46.0\nlon = 7.0\n[ground_truth]\ngps_rate_hz = 2.0\nattitude_rate_hz = 4.0\n"
    "[[transmitters]]\nid = 1\nposition = [20.0, 5.0, 0.0]\n"
    "[receiver]\nposition = [0.0, 0.0, 0.0]\ngps = true\nattitude = true\n"
)


def bound(text):
    pipe = Pipeline(loads_scene(text, "s.toml"))
    ports = {label: BufferPort(label) for label in pipe.labels}
    pipe.bind(ports, speed=0)
    return pipe, ports


def empty(seq, k, n=2):
    return encode_parva(seq, n, k, -1, -1, -1)


def test_step_writes_every_stream_in_scene_time_order():
    pipe, ports = bound(TRUTH)
    assert pipe.labels == ["arva", "gps", "attitude"]
    refs = []
    it = pipe.upcoming()
    for _ in range(7):
        refs.append(next(it))
    assert refs == [
        EpochRef(0.0, "arva", 0), EpochRef(0.0, "gps", 0), EpochRef(0.0, "attitude", 0),
        EpochRef(0.25, "attitude", 1), EpochRef(0.5, "gps", 1), EpochRef(0.5, "attitude", 2),
        EpochRef(0.75, "attitude", 3),
    ]
    assert pipe.step(1) == 1
    assert [r.next_k for r in pipe.routes] == [1, 2, 4]  # everything before t = 1 s
    assert pipe.step(2) == 3
    assert [r.next_k for r in pipe.routes] == [3, 6, 12]
    assert ports["gps"].data.count(b"$GPRMC") == 6 and ports["attitude"].data.count(b"$PASHR") == 12


def test_transmitters_move_add_silence_and_go():
    pipe, ports = bound(ONE)
    d1, a1 = measure_one([0, 0, 0], [1, 0, 0, 0], [20.0, 5.0, 0.0])
    pipe.step(1)
    assert bytes(ports["arva"].data) == encode_parva(0, 2, 1, 1, d1, a1) + empty(0, 2)
    pipe.set_transmitter(7, position=[10.0, 0.0, 0.0])  # new: added
    pipe.set_transmitter(1, enabled=False)  # silenced: its slot frees
    ports["arva"].data.clear()
    pipe.step(1)
    d7, a7 = measure_one([0, 0, 0], [1, 0, 0, 0], [10.0, 0.0, 0.0])
    assert bytes(ports["arva"].data) == encode_parva(1, 2, 1, 7, d7, a7) + empty(1, 2)
    pipe.set_transmitter(1, enabled=True)
    pipe.remove_transmitter(7)
    ports["arva"].data.clear()
    pipe.step(1)
    assert bytes(ports["arva"].data) == encode_parva(2, 2, 1, 1, d1, a1) + empty(2, 2)
    with pytest.raises(InputError, match="transmitter 3 is new: position required"):
        pipe.set_transmitter(3, enabled=True)
    with pytest.raises(InputError, match="no transmitter 3"):
        pipe.remove_transmitter(3)


def test_pinned_receiver_and_its_ground_truth_follow_the_pin():
    pipe, ports = bound(TRUTH)
    pipe.pin_receiver(0, position=[10.0, 5.0, 0.0])
    pipe.step(1)
    assert ports["arva"].data.startswith(b"$PARVA,0,1,1,1,917,0*")  # 10 m on the dipole axis
    assert pipe.streams["gps"].trajectory.positions[0].tolist() == [10.0, 5.0, 0.0]
    pipe.release_receiver(0)
    ports["arva"].data.clear()
    pipe.step(1)
    d, a = measure_one([0, 0, 0], [1, 0, 0, 0], [20.0, 5.0, 0.0])
    assert bytes(ports["arva"].data) == encode_parva(1, 1, 1, 1, d, a)


def test_faults_on_demand():
    pipe, ports = bound(ONE)
    line = len(encode_parva(0, 2, 1, 1, 1905, 21) + empty(0, 2))
    pipe.fault("arva", "disconnect", 2.0)  # scene seconds: epochs 0 and 1 are lost
    pipe.step(3)
    assert ports["arva"].data.startswith(b"$PARVA,2,") and len(ports["arva"].data) == line
    pipe.fault("arva", "corrupt", 5)
    ports["arva"].data.clear()
    pipe.step(1)
    sent = encode_parva(3, 2, 1, 1, 1905, 21) + empty(3, 2)
    got = bytes(ports["arva"].data)
    assert len(got) == len(sent) and got[5:] == sent[5:]
    assert all(a != b for a, b in zip(got[:5], sent[:5]))
    pipe.fault("arva", "stall", 10)
    pipe.step(1)
    assert pipe.route("arva").port.stalls == 1
    with pytest.raises(InputError, match="fault kind 'melt'"):
        pipe.fault("arva", "melt", 1)
    with pytest.raises(InputError, match="no stream 'gps'"):
        pipe.fault("gps", "stall", 1)


TX_GPS = (
    "spec = 1\n[origin]\nlat = 46.0\nlon = 7.0\n"
    "[[transmitters]]\nid = 3\ngps = true\nposition = [20.0, 5.0, 0.0]\n"
    "[receiver]\nposition = [0.0, 0.0, 0.0]\n"
)


def test_a_moved_transmitter_takes_its_gps_along():
    pipe, ports = bound(TX_GPS)
    assert pipe.labels == ["arva", "gps"]
    pipe.set_transmitter(3, position=[1.0, 2.0, 3.0])
    assert pipe.streams["gps"].trajectory.positions[0].tolist() == [1.0, 2.0, 3.0]
    pipe.set_transmitter(3, orientation=[0.0, 0.0, 0.0, 2.0])  # turned in place, normalised
    tr = pipe.streams["gps"].trajectory
    assert tr.positions[0].tolist() == [1.0, 2.0, 3.0] and tr.orientations[0].tolist() == [0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda p: p.set_transmitter(1, position=[1.0, "x", 2.0]), r"^position\[1\]: expected a number, got a string$"),
        (lambda p: p.set_transmitter(1, position=[True, 0, 0]), r"^position\[0\]: expected a number, got a boolean$"),
        (lambda p: p.set_transmitter(1, position=[float("inf"), 0, 0]), r"^position\[0\]: must be finite, got inf$"),
        (lambda p: p.set_transmitter(1, orientation=[0, 0, 0, 0]), "orientation: quaternion norm 0 is below 1e-09"),
        (lambda p: p.set_transmitter(1, orientation=[1, 0, 0]), "^orientation: expected 4 numbers, got 3$"),
        (lambda p: p.set_transmitter(1, enabled="yes"), "^set_transmitter.enabled: expected true or false, got a string$"),
        (lambda p: p.set_transmitter(-1, position=[0, 0, 0]), "^set_transmitter.id: must be in 0..65535, got -1$"),
        (lambda p: p.pin_receiver(3, position=[0, 0, 0]), "no receiver index 3"),
        (lambda p: p.step(-1), "step: n must be >= 0"),
    ],
)
def test_bad_requests_change_nothing(call, message):
    pipe, ports = bound(ONE)
    with pytest.raises(InputError, match=message):
        call(pipe)
    pipe.step(1)
    d1, a1 = measure_one([0, 0, 0], [1, 0, 0, 0], [20.0, 5.0, 0.0])
    assert bytes(ports["arva"].data) == encode_parva(0, 2, 1, 1, d1, a1) + empty(0, 2)


def test_a_vehicle_borne_receiver_cannot_be_pinned():
    scene = loads_scene(
        "spec = 1\n[[transmitters]]\nid = 1\nposition = [15.0, 0.0, 0.0]\n"
        "[receiver]\n[receiver.vehicle]\ncontroller = \"flux\"\n", "v.toml"
    )
    pipe = Pipeline(scene)
    with pytest.raises(InputError, match="receiver 1 rides a vehicle: its pose cannot be pinned"):
        pipe.pin_receiver(0, position=[0.0, 0.0, 1.0])
