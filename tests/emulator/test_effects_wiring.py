"""Effects as a scene asks for them: scene keys, pipeline placement, exact output."""

import subprocess
import sys
from functools import reduce

import numpy as np
import pytest

from emulator.receiver.receiver import Receiver
from emulator.scene.reader import default_scene, loads_scene
from emulator.pipeline import scene_streams
from emulator.testing.scene_toml import dumps
from firmware_proto.errors import SceneError
from scene_builders import link_faults_scene

PAPER = (
    "spec = 1\n"
    + "".join(
        f"[[transmitters]]\nid = {i}\nposition = {p}\n{{tx{i}}}\n"
        for i, p in ((1, "[20.0, 5.0, 0.0]"), (2, "[10.0, 0.0, 1.0]"), (3, "[20.0, -20.0, -1.0]"), (4, "[-6.0, 5.0, 0.0]"))
    )
    + "[receiver]\nchannels = 4\nposition = [0.0, 0.0, 0.0]\n"
)


def paper(extra="", **tx):
    return loads_scene(PAPER.format(**{f"tx{i}": tx.get(f"tx{i}", "") for i in range(1, 5)}) + extra, "p.toml")


def parva(seq, n, k, tx, d, delta):
    body = f"PARVA,{seq},{n},{k},{tx},{d},{delta}".encode()
    return b"$%s*%02X\r\n" % (body, reduce(lambda a, b: a ^ b, body, 0))


def test_ideal_scene_builds_no_effect_at_all():
    r = Receiver(default_scene())
    assert (r.noise, r.pulses, r.quantize) == (None, None, None)


def test_quantize_leds5_exact_sentences():
    s = paper("[effects]\nquantize = true\n[quantize]\nprofile = \"leds5\"\n")
    out = scene_streams(s)[0].render(0, 1)
    # Ideal deltas -62, 0, 21, -72 shown on 5 LEDs at -72, -36, 0, 36, 72.
    assert out == b"".join(
        [parva(0, 4, 1, 4, 761, -72), parva(0, 4, 2, 2, 926, 0), parva(0, 4, 3, 1, 1905, 36), parva(0, 4, 4, 3, 2808, -72)]
    )


def test_quantize_distance_display():
    s = paper("[effects]\nquantize = true\n[quantize]\nprofile = \"display_dm\"\n")
    ep = Receiver(s).next_batch(1).epochs
    assert ep.d.tolist() == [[760, 930, 1900, 2800]]  # 0.1 m below 10 m, 1 m above


ALONE = """spec = 1
[effects]
pulses = true
[pulses]
pulse_ms = 100
[[transmitters]]
id = 1
position = [20.0, 5.0, 0.0]
pulse_period_ms = 1300.0
[receiver]
channels = 2
position = [0.0, 0.0, 0.0]
"""


def test_pulses_report_rate_and_free_channels():
    # One transmitter alone with a 1300 ms period: reported in 1/1.3 of 1 s epochs.
    ep = Receiver(loads_scene(ALONE, "a.toml")).next_batch(13_000).epochs
    heard = ep.ids[:, 0] == 1
    assert abs(int(heard.sum()) - 10_000) <= 1
    # When it is silent its channel is empty, not stale.
    assert ep.ids[~heard].tolist() == [[-1, -1]] * int((~heard).sum())
    assert (ep.d[~heard] == -1).all() and (ep.d[heard, 0] == 1905).all()


def test_overlapping_pulses_hide_the_weaker():
    # 2 (926 cm) and 1 (1905 cm) pulse in phase: 1, the weaker, is never heard; 3 and 4
    # pulse in the gaps and are always heard.
    s = paper(
        "[effects]\npulses = true\n",
        tx1="pulse_period_ms = 1000.0\npulse_phase_ms = 0.0",
        tx2="pulse_period_ms = 1000.0\npulse_phase_ms = 50.0",
        tx3="pulse_period_ms = 1000.0\npulse_phase_ms = 400.0",
        tx4="pulse_period_ms = 1000.0\npulse_phase_ms = 700.0",
    )
    ep = Receiver(s).next_batch(100).epochs
    assert not (ep.ids == 1).any()
    assert ep.ids.tolist() == [[4, 2, 3, -1]] * 100


def test_pulses_seeded_replay():
    a = loads_scene(PAPER.format(tx1="", tx2="", tx3="", tx4="").replace("spec = 1\n", "spec = 1\nseed = 11\n[effects]\npulses = true\n"), "a")
    b = loads_scene(PAPER.format(tx1="", tx2="", tx3="", tx4="").replace("spec = 1\n", "spec = 1\nseed = 12\n[effects]\npulses = true\n"), "b")
    ra, ra2, rb = (scene_streams(x)[0].render(0, 200) for x in (a, a, b))
    assert ra == ra2 and ra != rb


@pytest.mark.parametrize(
    "extra, message",
    [
        ("[pulses]\npulse_ms = 80\n", "p.toml: pulses: parameters given but effects.pulses is not enabled"),
        ("[effects]\npulses = true\n[pulses]\npulse_ms = 50\n", "p.toml: pulses.pulse_ms: must be >= 70, got 50"),
        ("[effects]\npulses = true\n[pulses]\nwidth = 50\n", "p.toml: pulses.width: unknown key"),
        ("[effects]\nquantize = true\n[quantize]\nprofile = 5\n", "p.toml: quantize.profile: expected a string, got an integer"),
        ("[effects]\nlink_faults = true\n[link_faults]\nloss = 1.5\n", None),
        ("[effects]\nlink_faults = true\n[link_faults]\nstreams = [1]\n", "p.toml: link_faults.streams[0]: expected a string, got an integer"),
    ],
)
def test_effect_table_errors(extra, message):
    with pytest.raises(SceneError) as info:
        paper(extra)
    if message:
        assert str(info.value) == message
    else:
        assert str(info.value).startswith("p.toml: link_faults.loss: ")


def test_per_transmitter_pulse_keys_need_pulses():
    with pytest.raises(SceneError, match=r"^p.toml: transmitters\[0\].pulse_period_ms: given but effects.pulses is not enabled$"):
        paper(tx1="pulse_period_ms = 1000.0")


LOSSY = dumps(link_faults_scene(3, loss=0.02))


@pytest.mark.subprocess
def test_link_fault_loss_rate_on_the_wire(tmp_path):
    path = tmp_path / "lossy.toml"
    path.write_text(LOSSY)
    run = lambda: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "emulator.cli", "--scene", str(path), "--frames", "20000", "--speed", "0"],
        capture_output=True,
        timeout=120,
    )
    a, b = run(), run()
    assert a.stdout == b.stdout  # seeded
    offered = sum(len(parva(k % 65536, 1, 1, 1, 1905, 21)) for k in range(20_000))
    lost = offered - len(a.stdout)
    sigma = np.sqrt(offered * 0.02 * 0.98)
    assert abs(lost - 0.02 * offered) < 5 * sigma
    assert f"{lost} bytes dropped, {lost} faults injected".encode() in a.stderr


FAULTY = dumps(link_faults_scene(3, rate_hz=100.0, loss=0.02, corrupt=0.01))


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.timeout(60)
def test_faulted_stream_through_a_pty_in_real_time_equals_stdout_at_speed_0(tmp_path):
    """The faults a pyserial reader sees on a pty, paced in real time (one write per
    epoch), are byte for byte those of a --speed 0 run to stdout (large batched writes)."""
    import time

    import serial

    from emulator.testing import EmulatorProcess

    path = tmp_path / "faulty.toml"
    path.write_text(FAULTY)
    ref = subprocess.run([sys.executable, "-m", "emulator.cli", "--scene", str(path), "--frames", "2000",
                          "--speed", "0"], capture_output=True, timeout=60)  # fmt: skip
    assert ref.returncode == 0
    emu = EmulatorProcess("--scene", str(path), "--port", "pty", "--frames", "2000", "--speed", "5", "--delay", "1")
    got = bytearray()
    try:
        ser = emu.open(timeout=0.5)
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline:
            try:
                chunk = ser.read(ser.in_waiting or 1)  # small reads: pyserial drops a partial read at EOF
            except serial.SerialException:
                break  # the emulator finished and closed the pty
            if chunk:
                got += chunk
            elif emu.proc.poll() is not None:
                break
        # It ends by itself after its 2000 epochs (a SIGTERM here could race its exit).
        rc = emu.wait(timeout=30)
        err = emu.stderr()
    finally:
        emu.kill()
    assert rc == 0, err
    assert bytes(got) == ref.stdout
    summary = "2000 epochs sent (arva 2000), 1218 bytes dropped, 1824 faults injected"
    assert summary in err and summary in ref.stderr.decode()
