"""arva-emulate --control / --clock step end to end (BRIEF 9): the control channel over
real sockets, the step clock on real ptys, faults in scene time. Emulators are started
with the arva plugin's fixture or the harness library; every read has a timeout."""

import contextlib
import json
import os
import socket
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from functools import reduce

import pytest
import repo_paths
from scene_builders import one_tx

from emulator.testing import ControlClient, ControlReplyError, EmulatorProcess, read_lines
from firmware_proto.sentences import encode_parva

pytestmark = pytest.mark.subprocess

ONE = one_tx(rate_hz=1.0)
# Every stream kind and every effect but link faults (their own test below).
EVERYTHING = {
    "spec": 1,
    "seed": 42,
    "rate_hz": 2.0,
    "origin": {"lat": 46.0, "lon": 7.5, "alt": 1500.0},
    "ground_truth": {"gps_rate_hz": 1.0, "attitude_rate_hz": 5.0},
    "effects": {"noise": True, "pulses": True, "quantize": True, "ground_truth_error": True, "research_sentences": True},
    "pulses": {"period_ms": [900.0, 1100.0]},
    "quantize": {"profile": "leds5"},
    "ground_truth_error": {"gps_sigma_m": [1.0, 1.0, 2.0], "gps_dropout": 0.1, "attitude_sigma_deg": 1.0},
    "transmitters": [
        {"id": 1, "position": [20.0, 5.0, 0.0], "gps": True},
        {"id": 2, "path": [{"t": 0.0, "position": [5.0, 5.0, 0.0]}, {"t": 10.0, "position": [15.0, -5.0, 0.0]}]},
    ],
    "receivers": [
        {"id": 1, "channels": 2, "path": [{"t": 0.0, "position": [0.0, 0.0, 1.0]}, {"t": 8.0, "position": [10.0, 0.0, 1.0]}],
         "gps": True, "attitude": True},
        {"id": 4, "channels": 1, "position": [8.0, 8.0, 0.0]},
    ],
}


def parva(seq, d=1905, delta=21, tx=1):
    return encode_parva(seq, 1, 1, tx, d, delta)


def quiet(ser, wait=0.3):
    ser.timeout = wait
    data = ser.read(1)
    ser.timeout = 5.0
    return data == b""


def test_step_clock_gives_the_same_bytes_as_a_free_run_on_every_stream(arva_emulator, scene_file, tmp_path):
    """Two receivers, GPS and attitude streams, noise, pulses, quantize, ground-truth error
    and $PARVH: stepping 7 epochs (in uneven steps) writes exactly what a --speed 0
    --frames 7 run writes, stream by stream."""
    path = scene_file(EVERYTHING)
    out = tmp_path / "free"
    out.mkdir()
    labels = ["arva:1", "arva:4", "gps:rx1", "gps:tx1", "attitude"]
    files = [f"--stream={label}={out / label.replace(':', '-')}" for label in labels]
    free = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--scene", path, "--frames", "7", "--speed", "0", "--port", "pty", *files],
        capture_output=True, text=True, timeout=60,
    )
    assert free.returncode == 0, free.stderr
    emu = arva_emulator(scene=path, clock="step")
    assert sorted(emu.ports) == sorted(labels)
    assert emu.status()["streams"].keys() == set(labels)
    for n in (1, 2, 4):
        emu.step(n)
    assert emu.epoch == 7
    emu.stop()
    captured = emu.artefacts / "streams"
    for label in labels:
        name = label.replace(":", "-")
        expected = (out / name).read_bytes()
        assert expected  # something of every stream in 3.5 s of scene time
        assert (captured / f"{name}.bytes").read_bytes() == expected, label


@pytest.mark.slow
@pytest.mark.pty
def test_nothing_between_steps_and_every_stream_in_scene_time_order(arva_emulator):
    emu = arva_emulator(scene=EVERYTHING, clock="step")
    sers = {label: emu.open(label, timeout=5.0) for label in ("arva:1", "arva:4", "gps:rx1", "attitude")}
    try:
        assert all(quiet(s) for s in sers.values())
        emu.step(1)  # t in [0, 0.5): arva epoch 0 of each receiver, GPS epoch 0, attitude 0, 1, 2
        # Slot 1 and its $PARVH, then the empty slot 2 (no $PARVH for an empty slot).
        assert [line[:8] for line in read_lines(sers["arva:1"], 3)] == [b"$PARVA,0", b"$PARVH,0", b"$PARVA,0"]
        assert read_lines(sers["arva:4"], 2)[0].startswith(b"$PARVA,0,1,1,")
        assert [line[3:6] for line in read_lines(sers["gps:rx1"], 2)] == [b"RMC", b"GGA"]
        assert [line[:6] for line in read_lines(sers["attitude"], 3)] == [b"$PASHR"] * 3
        assert all(quiet(s, 0.2) for s in sers.values())
    finally:
        for s in sers.values():
            s.close()


def test_control_socket_is_private_and_removed_at_the_end(tmp_path):
    sock = tmp_path / "c.sock"
    emu = EmulatorProcess("--port", "pty", "--clock", "step", "--control", f"unix:{sock}")
    try:
        assert emu.control == f"unix:{sock}"
        assert stat.S_IMODE(os.stat(sock).st_mode) == 0o600
        client = ControlClient(emu.control, timeout=10)
        assert client.request("quit") == {"ok": True}
        assert emu.wait() == 0
        assert not sock.exists()
    finally:
        emu.kill()


def test_a_stale_socket_is_replaced_and_a_file_is_refused(tmp_path):
    stale = tmp_path / "stale.sock"
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(stale))
    s.close()  # bound, never listening: what a killed run leaves
    emu = EmulatorProcess("--port", "pty", "--clock", "step", "--control", f"unix:{stale}")
    emu.stop()
    plain = tmp_path / "notes.txt"
    plain.write_text("keep me")
    r = subprocess.run([sys.executable, "-m", "emulator.cli", "--port", "pty", "--control", f"unix:{plain}"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert r.stderr == f"arva-emulate: --control unix:{plain}: exists and is not a socket (refusing to replace it)\n"
    assert plain.read_text() == "keep me"


@pytest.mark.parametrize(
    "args, error",
    [
        (["--control", "tcp:0.0.0.0:0"], "--control tcp:0.0.0.0:0: 0.0.0.0 is not a loopback address (the channel has "
         "no authentication; add --control-any-host to serve other hosts)"),
        (["--clock", "step"], "--clock step: nothing would ever be emitted without --control ADDRESS to send 'step'"),
        (["--control-any-host"], "--control-any-host: given without --control"),
    ],
)
def test_refused_command_lines(args, error):
    r = subprocess.run([sys.executable, "-m", "emulator.cli", "--port", "pty", *args],
                       capture_output=True, text=True, timeout=30)
    assert (r.returncode, r.stderr, r.stdout) == (2, f"arva-emulate: {error}\n", "")


def test_tcp_loopback_and_any_host():
    emu = EmulatorProcess("--port", "pty", "--clock", "step", "--control", "tcp:127.0.0.1:0")
    try:
        host, port = emu.control.removeprefix("tcp:").rsplit(":", 1)
        assert host == "127.0.0.1" and int(port) > 0
        assert ControlClient(emu.control).request("status")["clock"] == "step"
    finally:
        emu.stop()
    emu = EmulatorProcess("--port", "pty", "--clock", "step", "--control", "tcp:0.0.0.0:0", "--control-any-host")
    try:
        port = emu.control.rsplit(":", 1)[1]
        assert ControlClient(f"tcp:127.0.0.1:{port}").request("status")["epoch"] == 0
    finally:
        emu.stop()


@pytest.mark.pty
def test_garbage_gets_one_error_reply_each_and_changes_nothing(arva_emulator):
    emu = arva_emulator(scene=ONE, clock="step")
    c = emu.client
    before = emu.truth()
    hostile = [
        b"hello", b"\xff\xfe\x00", b"{}", b"[]", b'{"op": "dance"}', b'{"op": "step", "n": -3}',
        b'{"op": "set_transmitter", "id": 1, "position": [1, 2, "x"]}',
        b'{"op": "set_transmitter", "id": 1, "orientation": [0, 0, 0, 0]}',
        b'{"op": "set_transmitter", "id": 9, "enabled": false}',  # new id without a position
        b'{"op": "remove_transmitter", "id": 9}', b'{"op": "set_receiver", "id": 3, "position": [0, 0, 0]}',
        b'{"op": "fault", "stream": "gps", "kind": "corrupt", "bytes": 3}',
        b'{"op": "pause"}', b'{"op": "resume"}', b"{" * 70_000,
    ]
    for line in hostile:
        reply = c.send_line(line)
        assert reply["ok"] is False and isinstance(reply["error"], str) and "\n" not in reply["error"], line[:40]
    assert c.send_line(b'{"op": "remove_transmitter", "id": 9}')["error"] == "remove_transmitter: no transmitter 9 (ids: 1)"
    # the pipeline's own errors, named by the op once (the server's rule)
    assert c.send_line(hostile[8])["error"] == "set_transmitter: transmitter 9 is new: position required"
    assert c.send_line(hostile[11])["error"] == "fault: no stream 'gps' (streams: arva)"
    assert c.send_line(b'{"op": "pause"}')["error"] == (
        "pause: the step clock emits only on step (pause/resume are for --clock real)")
    assert emu.truth() == before
    with emu.open(timeout=5) as ser:
        assert emu.step(2) == 2
        assert read_lines(ser, 2) == [parva(0), parva(1)]


def test_several_clients_each_get_their_own_replies_and_see_each_others_changes(arva_emulator):
    emu = arva_emulator(scene=ONE, clock="step")
    a = ControlClient(emu.process.control, timeout=10)
    b = ControlClient(emu.process.control, timeout=10)
    half = socket.socket(socket.AF_UNIX)
    half.connect(emu.process.control.removeprefix("unix:"))
    half.sendall(b'{"op": "sta')  # a client that never finishes its line, then vanishes
    try:
        a.request("set_transmitter", id=5, position=[3.0, 0.0, 0.0])
        assert [t["id"] for t in b.request("truth")["transmitters"]] == [1, 5]
        assert b.request("step", n=3)["epoch"] == 3
        assert a.request("status")["epoch"] == 3
        half.close()
        # Requests pipelined on one connection: one reply each, in order.
        a._sock.sendall(b'{"op": "status"}\n{"op": "nope"}\n\n{"op": "step"}\n')
        replies = [json.loads(a._read_line()) for _ in range(3)]
        assert [r["ok"] for r in replies] == [True, False, True] and replies[2]["epoch"] == 4
    finally:
        a.close()
        b.close()


def test_step_respects_frames_and_quit_exits_zero(scene_file, tmp_path):
    emu = EmulatorProcess("--scene", scene_file(ONE), "--port", "pty", "--clock", "step", "--frames", "3",
                          "--control", f"unix:{tmp_path}/c.sock")
    try:
        c = ControlClient(emu.control, timeout=10)
        assert c.request("step", n=2)["epoch"] == 2
        with pytest.raises(ControlReplyError, match=r"step: n = 2 but only 1 epochs are left \(--frames\)"):
            c.request("step", n=2)
        assert c.request("step")["epoch"] == 3
        assert c.request("quit") == {"ok": True}
        assert emu.wait() == 0
        assert "3 epochs sent (arva 3)" in emu.stderr()
    finally:
        emu.kill()


@pytest.mark.pty
def test_unplug_in_scene_time_re_announces_the_pty(arva_emulator):
    emu = arva_emulator(scene=ONE, clock="step")
    first_pty = emu.process.ports["arva"]
    assert os.path.realpath(emu.port) == first_pty
    with emu.open(timeout=5) as ser:
        emu.step(2)
        assert read_lines(ser, 2) == [parva(0), parva(1)]
        assert emu.fault("disconnect", seconds=2.0) == 2
    assert not os.path.exists(emu.port)  # unplugged: the pty is gone
    emu.step(2)  # epochs 2 and 3 (t = 2 s, 3 s) fall in the outage [2 s, 4 s)
    assert not os.path.exists(emu.port)
    emu.step(1)  # t = 4 s: the port is back, on a new pty (announced again) the symlink follows
    deadline = time.monotonic() + 5
    while len(emu.process.announcements) < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert emu.process.announcements[0] == f"arva {first_pty}"
    assert emu.process.announcements[1].startswith("control unix:")
    assert emu.process.announcements[2] == f"arva {emu.process.ports['arva']}"
    assert os.path.realpath(emu.port) == emu.process.ports["arva"]
    with emu.open(timeout=5) as ser:
        emu.step(1)
        assert read_lines(ser, 1) == [parva(5)]
    captured = (emu.artefacts / "streams" / "arva.bytes").read_bytes()
    assert captured == b"".join(parva(k) for k in (0, 1, 4, 5))


@pytest.mark.pty
def test_stall_and_corrupt_in_scene_time(arva_emulator):
    emu = arva_emulator(scene=ONE, clock="step")
    with emu.open(timeout=5) as ser:
        emu.fault("stall", ms=1500)  # from t = 0 to 1.5 s: epochs 0 and 1 held
        emu.step(1)
        assert quiet(ser)
        emu.step(1)
        assert quiet(ser)
        emu.step(1)  # t = 2 s: the held bytes go out, in order, with epoch 2
        assert read_lines(ser, 3) == [parva(0), parva(1), parva(2)]
        emu.fault("corrupt", bytes=4)
        emu.step(1)
        got = read_lines(ser, 1)[0]
        sent = parva(3)
        assert len(got) == len(sent) and got[4:] == sent[4:] and all(x != y for x, y in zip(got[:4], sent[:4]))


@contextlib.contextmanager
def real_clock_reader(arva_emulator, rate_hz: float) -> Iterator[tuple[object, object]]:
    """(emulator, its pty) for ONE at ``rate_hz`` on the real clock at 1x, once the first
    two epochs have been read."""
    emu = arva_emulator(scene=dict(ONE, rate_hz=rate_hz), clock="real", speed=1.0)
    with emu.open(timeout=5) as ser:
        read_lines(ser, 2)
        yield emu, ser


@pytest.mark.slow
@pytest.mark.pty
def test_real_clock_pause_resume_skips_missed_epochs(arva_emulator):
    emu = arva_emulator(scene=dict(ONE, rate_hz=10.0), clock="real", speed=1.0)
    with emu.open(timeout=5) as ser:
        lines = read_lines(ser, 3)
        assert lines[0].startswith(b"$PARVA,")
        paused_at = emu.pause()
        time.sleep(0.15)
        ser.reset_input_buffer()  # whatever was written before the pause took effect
        assert quiet(ser, 1.0)
        resumed_at = emu.resume()
        assert resumed_at >= paused_at + 9  # ~1.15 s at 10 Hz went by, not replayed
        seq = int(read_lines(ser, 1)[0].split(b",")[1])
        assert seq >= resumed_at - 1
        with pytest.raises(ControlReplyError, match="step: the emulator runs on the real clock"):
            emu.step()
    assert emu.stop() == 0


@pytest.mark.slow
@pytest.mark.pty
def test_real_clock_changes_take_effect_from_the_epoch_named(arva_emulator):
    with real_clock_reader(arva_emulator, 20.0) as (emu, ser):
        k = emu.set_transmitter(1, position=[10.0, 0.0, 0.0])
        lines = read_lines(ser, 40)
        by_seq = {int(line.split(b",")[1]): line for line in lines}
        assert by_seq[k] == parva(k, 917, 0)
        assert by_seq[k - 1] == parva(k - 1) if k - 1 in by_seq else True


def test_a_vehicle_borne_receiver_steps_but_cannot_be_pinned(arva_emulator):
    scene = repo_paths.SCENES / "case_study_1.toml"
    emu = arva_emulator(scene=str(scene), clock="step")
    start = emu.truth()["receivers"][0]["position"]
    with pytest.raises(ControlReplyError) as info:
        emu.set_receiver(position=[0.0, 0.0, 10.0])
    assert info.value.error == "set_receiver: receiver 1 rides a vehicle: its pose cannot be pinned"
    emu.step(3)
    assert emu.truth()["receivers"][0]["position"] != start  # the vehicle flew


def test_a_bad_scene_is_a_clear_error_from_the_fixture(arva_emulator):
    from emulator.testing import EmulatorError

    with pytest.raises(EmulatorError) as info:
        arva_emulator(scene={"spec": 1, "receiver": {"position": [0, 0, 0]}, "colour": "red"})
    assert str(info.value).startswith("arva-emulate exited with status 2: ")
    assert str(info.value).endswith(".toml: colour: unknown key")


@pytest.mark.pty
def test_set_receiver_by_id_pins_that_receiver_only(arva_emulator):
    scene = {
        "spec": 1,
        "transmitters": [{"id": 1, "position": [20.0, 5.0, 0.0]}],
        "receivers": [{"id": 1, "position": [0.0, 0.0, 0.0]}, {"id": 7, "position": [0.0, 0.0, 0.0]}],
    }
    emu = arva_emulator(scene=scene, clock="step")
    with emu.open("arva:1", timeout=5) as a, emu.open("arva:7", timeout=5) as b:
        assert emu.set_receiver(position=[10.0, 5.0, 0.0], id=7) == 0
        emu.step()
        assert read_lines(a, 1) == [parva(0)]
        assert read_lines(b, 1) == [parva(0, 917, 0)]  # 10 m on the dipole axis
        emu.set_receiver(id=7, path="resume")
        emu.step()
        assert read_lines(b, 1) == [parva(1)]


@pytest.mark.slow
@pytest.mark.pty
def test_real_clock_stall_holds_bytes_in_scene_time_and_loses_none(arva_emulator):
    with real_clock_reader(arva_emulator, 10.0) as (emu, ser):
        k = emu.fault("stall", ms=600)
        t_fault = time.monotonic()
        arrivals = []
        for _ in range(15):
            line = read_lines(ser, 1)[0]
            arrivals.append((time.monotonic(), int(line.split(b",")[1])))
        assert emu.status()["epoch"] > k  # the channel answered throughout
    seqs = [s for _, s in arrivals]
    assert seqs == list(range(seqs[0], seqs[0] + 15))  # in order, none lost
    # ~0.6 s of silence while the bytes were held, then the held epochs at once.
    assert arrivals[0][0] - t_fault >= 0.4
    assert arrivals[4][0] - arrivals[0][0] < 0.2  # 5 epochs unheld would take 0.4 s
