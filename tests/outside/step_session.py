"""A firmware team's test, run from a folder outside this repository with only the
installed package (tests/emulator/testing/test_hil_outside.py copies it to a temporary folder and runs
pytest there): the ``arva_emulator`` fixture in step mode, transmitters moved, added,
silenced and removed, the receiver pinned, and exactly the model's sentences read epoch
by epoch, with nothing emitted between steps."""

import math

import pytest

from emulator.receiver.model import measure_one
from emulator.testing import ControlReplyError, read_lines
from firmware_proto.sentences import encode_parva

CHANNELS = 2
IDENTITY = (1.0, 0.0, 0.0, 0.0)
YAW_90 = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
SCENE = {
    "spec": 1,
    "seed": 11,
    "rate_hz": 2.0,
    "transmitters": [{"id": 1, "position": [20.0, 5.0, 0.0]}],
    "receiver": {"channels": CHANNELS, "position": [0.0, 0.0, 0.0]},
}


def model_epoch(seq, rx, txs):
    """The sentences of one epoch from the model itself: every transmitter measured,
    outer ones dropped, sorted by (d, id), padded with empty slots."""
    slots = []
    for tx_id, (pos, quat) in sorted(txs.items()):
        d, delta = measure_one(rx[0], rx[1], pos, quat)
        if d >= 0:
            slots.append((d, tx_id, delta))
    slots = sorted(slots)[:CHANNELS]
    slots += [(-1, -1, -1)] * (CHANNELS - len(slots))
    return [encode_parva(seq, CHANNELS, k + 1, tx_id, d, delta) for k, (d, tx_id, delta) in enumerate(slots)]


def quiet(ser):
    """Nothing is waiting on the port (and nothing arrives within 0.3 s)."""
    ser.timeout = 0.3
    data = ser.read(1)
    ser.timeout = 5.0
    return data == b""


def test_step_session(arva_emulator):
    emu = arva_emulator(scene=SCENE, clock="step")
    rx = ((0.0, 0.0, 0.0), IDENTITY)
    txs = {1: ((20.0, 5.0, 0.0), IDENTITY)}
    with emu.open(timeout=5.0) as ser:
        assert quiet(ser)  # the step clock emits nothing on its own
        seq = 0

        def step_and_check():
            nonlocal seq
            assert emu.step() == seq + 1
            assert read_lines(ser, CHANNELS) == model_epoch(seq, rx, txs)
            assert quiet(ser)
            seq += 1

        step_and_check()
        step_and_check()
        assert emu.epoch == 2
        # Move transmitter 1 (takes effect from the next epoch, which the reply names).
        assert emu.set_transmitter(1, position=[10.0, 0.0, 0.0]) == 2
        txs[1] = ((10.0, 0.0, 0.0), IDENTITY)
        assert quiet(ser)
        step_and_check()
        # Add transmitter 2, yawed 90 degrees, closer than 1.
        emu.set_transmitter(2, position=[0.0, 6.0, 0.0], orientation=list(YAW_90))
        txs[2] = ((0.0, 6.0, 0.0), YAW_90)
        step_and_check()
        # Silence 1: its slot frees.
        emu.set_transmitter(1, enabled=False)
        silenced = txs.pop(1)
        step_and_check()
        # Pin the receiver next to 2, turned.
        emu.set_receiver(position=[1.0, 4.0, 0.0], orientation=list(YAW_90))
        rx = ((1.0, 4.0, 0.0), YAW_90)
        step_and_check()
        truth = emu.truth()
        assert truth["epoch"] == seq
        assert truth["receivers"] == [{"id": 1, "position": [1.0, 4.0, 0.0], "orientation": pytest.approx(list(YAW_90))}]
        assert [(t["id"], t["enabled"]) for t in truth["transmitters"]] == [(1, False), (2, True)]
        # A refused request changes nothing.
        with pytest.raises(ControlReplyError, match="new: position required"):
            emu.set_transmitter(3, enabled=True)
        step_and_check()
        # Remove 2, bring 1 back.
        emu.remove_transmitter(2)
        del txs[2]
        emu.set_transmitter(1, enabled=True)
        txs[1] = silenced
        step_and_check()
        # Several epochs in one step, then the receiver back on its (static) scene path.
        emu.set_receiver(path="resume")
        rx = ((0.0, 0.0, 0.0), IDENTITY)
        assert emu.step(3) == seq + 3
        assert read_lines(ser, 3 * CHANNELS) == [s for k in range(3) for s in model_epoch(seq + k, rx, txs)]
        assert quiet(ser)
    assert emu.stop() == 0
