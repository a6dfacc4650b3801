"""One pipeline, every door the same bytes: ``arva-emulate --port - --speed 0`` and
``arvaemu://`` over seeded scenes with every effect on (noise, pulses, quantize,
$PARVH, link faults with loss, corruption, splits, stalls and outages)."""

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import emulator.urlhandler  # noqa: F401  (registers arvaemu://)
from emulator.cli import main
from emulator.output.link_faults import FaultyPort
from emulator.output.ports import BufferPort
from emulator.pipeline import Pipeline, stream_layout
from emulator.scene.reader import loads_scene


def _num(x: float) -> str:
    return repr(float(x))


@st.composite
def scenes(draw):
    """TOML text of a random scene with every effect on."""
    seed = draw(st.integers(0, 2**32))
    rate = draw(st.sampled_from([1.0, 2.0, 4.0]))
    n_tx = draw(st.integers(1, 4))
    n_rx = draw(st.integers(1, 2))
    coord = st.floats(-40, 40, allow_nan=False)
    lines = [f"spec = 1\nseed = {seed}\nrate_hz = {rate}\n"]
    lines.append(
        "[effects]\nnoise = true\nresearch_sentences = true\npulses = true\nquantize = true\nlink_faults = true\n"
    )
    lines.append(f"[pulses]\ndrift_ppm = {_num(draw(st.floats(0, 100)))}\noverlap = \"{draw(st.sampled_from(['weaker', 'both']))}\"\n")
    lines.append(f"[quantize]\nprofile = \"{draw(st.sampled_from(['leds5', 'leds3', 'display_dm', 'display_m']))}\"\n")
    every = draw(st.sampled_from([0.0, 3.0, 5.0]))
    lines.append(
        "[link_faults]\n"
        f"loss = {_num(draw(st.floats(0, 0.2)))}\ncorrupt = {_num(draw(st.floats(0, 0.2)))}\n"
        f"split = {_num(draw(st.floats(0, 1)))}\nstall = {_num(draw(st.floats(0, 1)))}\nstall_ms = 1.0\n"
        f"disconnect_every_s = {every}\ndisconnect_s = {1.0 if every else 2.0}\n"
    )
    for i in range(n_tx):
        pos = [draw(coord), draw(coord), draw(st.floats(-3, 0))]
        yaw = draw(st.floats(-1, 1))
        lines.append(
            f"[[transmitters]]\nid = {i + 1}\nposition = [{', '.join(map(_num, pos))}]\n"
            f"orientation = [1.0, 0.0, 0.0, {_num(yaw)}]\n"
        )
    for j in range(n_rx):
        head = "[receiver]" if n_rx == 1 else "[[receivers]]"
        start = [draw(coord), draw(coord), 0.0]
        end = [draw(coord), draw(coord), 1.0]
        lines.append(
            f"{head}\nid = {j + 1}\nchannels = {draw(st.integers(1, 3))}\npath = [\n"
            f"  {{ t = 0.0, position = [{', '.join(map(_num, start))}] }},\n"
            f"  {{ t = 20.0, position = [{', '.join(map(_num, end))}], orientation = [0.9, 0.0, 0.1, 0.3] }},\n]\n"
        )
    return "".join(lines)


def read_url(url: str) -> bytes:
    out = bytearray()
    with serial.serial_for_url(url, timeout=1) as port:
        while chunk := port.read(4096):
            out += chunk
    return bytes(out)


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=scenes(), frames=st.integers(1, 30))
def test_arva_emulate_and_arvaemu_give_identical_bytes(tmp_path_factory, capsysbinary, text, frames):
    d = tmp_path_factory.mktemp("doors")
    path = d / "s.toml"
    path.write_text(text)
    scene = loads_scene(text, str(path))
    labels = [info.label for info in stream_layout(scene)]
    argv = ["--scene", str(path), "--port", "-", "--speed", "0", "--frames", str(frames)]
    files = {}
    for label in labels[1:]:  # the other receivers to files (stdout carries one stream)
        files[label] = d / (label.replace(":", "-") + ".out")
        argv += ["--stream", f"{label}={files[label]}"]
    capsysbinary.readouterr()
    assert main(argv) == 0
    cli = {labels[0]: capsysbinary.readouterr().out}
    cli.update({label: f.read_bytes() for label, f in files.items()})
    for i, rx in enumerate(scene.receivers):
        query = f"?speed=0&frames={frames}" + (f"&receiver={rx.id}" if len(scene.receivers) > 1 else "")
        assert read_url(f"arvaemu://{path}{query}") == cli[labels[i]], labels[i]


def test_full_loss_drops_every_byte_through_both_doors(tmp_path, capsysbinary):
    """The defect that started it: loss = 1 dropped everything on stdout while
    arvaemu:// returned every epoch intact."""
    path = tmp_path / "lossy.toml"
    path.write_text(
        "spec = 1\n[effects]\nlink_faults = true\n[link_faults]\nloss = 1.0\n"
        "[[transmitters]]\nid = 1\nposition = [20.0, 5.0, 0.0]\n[receiver]\nposition = [0.0, 0.0, 0.0]\n"
    )
    assert main(["--scene", str(path), "--port", "-", "--speed", "0", "--frames", "3"]) == 0
    assert capsysbinary.readouterr().out == b""
    with serial.serial_for_url(f"arvaemu://{path}?speed=0&frames=3", timeout=0.2) as port:
        assert port.read(100) == b""


def test_only_the_streams_asked_for_are_built_and_faults_keep_their_stream_index():
    text = (
        "spec = 1\nseed = 3\n[effects]\nlink_faults = true\n[link_faults]\ncorrupt = 0.5\n"
        "[[transmitters]]\nid = 1\nposition = [20.0, 5.0, 0.0]\n"
        "[[receivers]]\nid = 4\nposition = [0.0, 0.0, 0.0]\n[[receivers]]\nid = 9\nposition = [1.0, 0.0, 0.0]\n"
    )
    scene = loads_scene(text, "two.toml")
    whole, part = Pipeline(scene), Pipeline(scene, ["arva:9"])
    assert whole.labels == ["arva:4", "arva:9"] and part.labels == ["arva:9"]
    bufs = {label: BufferPort(label) for label in whole.labels}
    whole.bind(bufs, speed=0)
    mine = BufferPort("arva:9")
    (route,) = part.bind({"arva:9": mine}, speed=0)
    assert isinstance(route.port, FaultyPort)
    whole.step(5)
    route.send(5, part.clock)
    assert mine.data == bufs["arva:9"].data and mine.data != bufs["arva:4"].data


def test_closed_loop_receiver_through_both_doors(tmp_path, capsysbinary):
    """A receiver on a flux-following UAV, noise, quantize and link faults on."""
    path = tmp_path / "uav.toml"
    path.write_text(
        "spec = 1\nseed = 11\n[effects]\nnoise = true\nquantize = true\nresearch_sentences = true\n"
        "link_faults = true\n[quantize]\nprofile = \"leds5\"\n"
        "[link_faults]\ncorrupt = 0.01\nloss = 0.01\ndisconnect_every_s = 7.0\ndisconnect_s = 2.0\n"
        "[[transmitters]]\nid = 1\nposition = [20.0, 5.0, 0.0]\n"
        "[receiver]\nchannels = 2\n[receiver.vehicle]\ncontroller = \"flux\"\n"
    )
    assert main(["--scene", str(path), "--port", "-", "--speed", "0", "--frames", "40"]) == 0
    cli = capsysbinary.readouterr().out
    assert cli.count(b"$PARVA") > 40  # most of 80 slots survive the faults
    assert read_url(f"arvaemu://{path}?speed=0&frames=40") == cli
