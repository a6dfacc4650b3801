"""The bench's MAVLink attitude reader: real pymavlink-encoded frames -> Attitude records,
hostile streams, and a logged session whose export takes the receiver's attitude from an
autopilot's ATTITUDE_QUATERNION over TCP (pyserial's socket://)."""

import math
import socket
import subprocess
import sys
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from hypothesis import given
from hypothesis import strategies as st
from scene_builders import FIELD_START_UTC, field_scene

from bench.export import export_rows
from bench.ground_truth.mavlink import MavlinkAttitudeReader
from bench.records import decoder_for
from bench.session import read_jsonl, read_manifest
from emulator.frames.attitude import hpr_to_quaternion
from emulator.testing import EmulatorProcess

pytest.importorskip("pymavlink")
from pymavlink.dialects.v10 import common as mavlink1  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

C45 = math.sqrt(0.5)


def encoder(v1: bool = False):
    return (mavlink1 if v1 else mavlink2).MAVLink(None, srcSystem=1, srcComponent=1)


def att_q(enc, ms, q, v1=False):
    dialect = mavlink1 if v1 else mavlink2
    if v1:
        return dialect.MAVLink_attitude_quaternion_message(ms, *q, 0.0, 0.0, 0.0).pack(enc)
    return dialect.MAVLink_attitude_quaternion_message(ms, *q, 0.0, 0.0, 0.0, [0.0] * 4).pack(enc)


def att_euler(enc, ms, roll, pitch, yaw):
    return mavlink2.MAVLink_attitude_message(ms, roll, pitch, yaw, 0.0, 0.0, 0.0).pack(enc)


def heartbeat(enc):
    return mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc)


def test_identity_ned_attitude_is_heading_north():
    # FRD aligned with NED: body x north, level. In our frames FLU body x -> ENU north is
    # a +90 deg yaw about up: [cos 45, 0, 0, sin 45].
    r = MavlinkAttitudeReader()
    frame = att_q(encoder(), 1234, (1.0, 0.0, 0.0, 0.0))
    assert len(frame) == 20  # MAVLink 2 drops the payload's trailing zero bytes
    (a,) = r.feed(frame)
    assert a.time_boot_ms == 1234
    # Angles come back from the quaternion (atan2 of products of sqrt(1/2)): 1e-12 deg.
    assert abs(a.heading) < 1e-12 and abs(a.roll) < 1e-12 and abs(a.pitch) < 1e-12
    np.testing.assert_allclose(a.quaternion, [C45, 0.0, 0.0, C45], atol=1e-15)
    assert a.utc is None and a.time_of_day is None
    assert dict(r.stats) == {"bytes": 20, "messages": 1, "attitudes": 1}


def test_yaw_east_is_our_identity_and_mavlink1_frames_are_read():
    # A 90 deg turn about NED down: body x east = ENU x, level: our identity quaternion.
    # (q1..q4 are float32 on the wire: cos 45 deg to 1e-7.)
    for v1 in (False, True):
        r = MavlinkAttitudeReader()
        frame = att_q(encoder(v1), 7, (C45, 0.0, 0.0, C45), v1=v1)
        assert frame[0] == (0xFE if v1 else 0xFD)
        (a,) = r.feed(frame)
        np.testing.assert_allclose(a.quaternion, [1.0, 0.0, 0.0, 0.0], atol=1e-7)
        assert abs(a.heading - 90.0) < 1e-5 and abs(a.roll) < 1e-12 and abs(a.pitch) < 1e-12
        assert r.stats["bytes"] == len(frame)


def test_euler_attitude_uses_the_pashr_convention():
    r = MavlinkAttitudeReader()
    (a,) = r.feed(att_euler(encoder(), 50, math.radians(-20.0), math.radians(30.0), math.radians(-90.0)))
    # yaw -90 deg is heading 270 (west); float32 radians on the wire: 1e-5 deg.
    assert abs(a.heading - 270.0) < 1e-5 and abs(a.roll + 20.0) < 1e-5 and abs(a.pitch - 30.0) < 1e-5
    np.testing.assert_allclose(a.quaternion, hpr_to_quaternion(270.0, -20.0, 30.0), atol=1e-7)
    # Pitch +30: body x has an up component of sin 30 = 0.5.
    w, x, y, z = a.quaternion
    assert abs(2 * (x * z - w * y) - 0.5) < 1e-6


def test_euler_after_a_quaternion_is_ignored_and_other_messages_counted():
    enc = encoder()
    stream = (heartbeat(enc) + att_euler(enc, 1, 0.0, 0.0, 0.0) + att_q(enc, 2, (1.0, 0.0, 0.0, 0.0))
              + att_euler(enc, 2, 0.0, 0.0, 0.0) + heartbeat(enc))  # fmt: skip
    r = MavlinkAttitudeReader()
    assert [a.time_boot_ms for a in r.feed(stream)] == [1, 2]
    assert dict(r.stats) == {"bytes": len(stream), "messages": 5, "attitudes": 2, "ignored": 3}


def test_degenerate_quaternion_is_malformed_not_a_record():
    r = MavlinkAttitudeReader()
    assert r.feed(att_q(encoder(), 9, (0.0, 0.0, 0.0, 0.0))) == []
    assert r.feed(att_q(encoder(), 9, (math.nan, 0.0, 0.0, 1.0))) == []
    assert (r.stats["malformed"], r.stats["attitudes"]) == (2, 0)


def test_every_single_bit_flip_is_caught_and_the_next_frame_survives():
    """Flip each bit of one frame in turn, followed by a good frame."""
    enc = encoder()
    bad_src = att_euler(enc, 111, 0.5, 0.25, 0.125)  # 28 bytes: the zero rates are truncated
    header = 10
    good = att_q(enc, 222, (1.0, 0.0, 0.0, 0.0))
    payload_flips = 0
    for bit in range(len(bad_src) * 8):
        bad = bytearray(bad_src)
        bad[bit // 8] ^= 1 << (bit % 8)
        r = MavlinkAttitudeReader()
        out = r.feed(bytes(bad) + good) + r.flush()
        # Nothing from the damaged frame is ever reported as an attitude.
        assert [a.time_boot_ms for a in out] in ([222], []), bit
        if bit // 8 >= 3:  # past magic, length and flags the frame boundary is intact
            assert [a.time_boot_ms for a in out] == [222], bit
        if bit // 8 >= header:  # payload and CRC: the CRC catches it
            assert r.stats["bad_checksum"] == 1, bit
            payload_flips += 1
    assert payload_flips == (len(bad_src) - header) * 8 == 144


frame_values = st.tuples(
    st.integers(0, 2**32 - 1),
    st.lists(st.floats(-1.0, 1.0, width=32), min_size=4, max_size=4).filter(lambda q: sum(c * c for c in q) > 0.01),
)
# Junk with no MAVLink start byte (0xFD, 0xFE): a start byte inside junk legitimately makes
# the parser read a bogus frame of up to 280 bytes, which may swallow a following frame.
junk = st.binary(max_size=40).map(lambda b: bytes(c for c in b if c not in (0xFD, 0xFE)))


@given(st.lists(st.tuples(junk, frame_values, st.booleans()), max_size=12), st.lists(st.integers(1, 64), max_size=20))
def test_hostile_stream_any_chunking_decodes_every_frame_once_in_order(items, cuts):
    enc = encoder()
    stream = b"".join(j + att_q(enc, ms, q, v1=False) + (heartbeat(enc) if hb else b"") for j, (ms, q), hb in items)
    r = MavlinkAttitudeReader()
    out, pos = [], 0
    for n in cuts:
        out += r.feed(stream[pos : pos + n])
        pos += n
    out += r.feed(stream[pos:]) + r.flush()
    assert [a.time_boot_ms for a in out] == [ms for _, (ms, _), _ in items]
    assert r.stats["junk_bytes"] == sum(len(j) for j, _, _ in items)
    assert r.pending == 0
    for a, (_, (_, q), _) in zip(out, items):
        assert all(math.isfinite(c) for c in a.quaternion) and abs(math.fsum(c * c for c in a.quaternion) - 1) < 1e-12


def test_torn_last_frame_is_counted_at_flush():
    frame = att_euler(encoder(), 5, 0.5, 0.25, 0.125)
    r = MavlinkAttitudeReader()
    assert r.feed(frame[:20]) == [] and r.pending == 20
    assert r.flush() == []
    assert (r.stats["fragments"], r.stats["junk_bytes"], r.pending) == (1, 20, 0)
    assert [a.time_boot_ms for a in r.feed(frame)] == [5]  # and the reader goes on


def test_record_decoder_and_bad_formats():
    dec = decoder_for("attitude", "mavlink")
    recs = dec.feed(att_q(encoder(), 77, (C45, 0.0, 0.0, C45)) + b"\x00\x01")
    assert recs[0]["time_boot_ms"] == 77 and recs[0]["time"] is None
    assert recs[1] == {"error": {"junk_bytes": 2}}
    with pytest.raises(ValueError, match=r"a gps device cannot speak 'mavlink' \(one of: nmea\)"):
        decoder_for("gps", "mavlink")


def bench(*args):
    return subprocess.run([sys.executable, "-m", "bench.cli", *args], capture_output=True, text=True, timeout=60)


@pytest.mark.subprocess
def test_format_option_is_checked_on_the_command_line(tmp_path):
    p = bench("log", "--arva", "loop://", "--gps", "loop://,format=mavlink", "--out", str(tmp_path / "s"))
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.splitlines()[-1] == (
        "arva-bench log: error: argument --gps: 'loop://,format=mavlink': gps devices take format nmea, got 'mavlink'"
    )
    p = bench("log", "--arva", "loop://,format=nmea", "--out", str(tmp_path / "s"))
    assert p.returncode == 2 and "arva devices take no format option, got 'nmea'" in p.stderr
    p = bench("log", "--arva", "loop://", "--attitude", "loop://,format=ubx", "--out", str(tmp_path / "s"))
    assert p.returncode == 2 and "attitude devices take format nmea or mavlink, got 'ubx'" in p.stderr
    assert not (tmp_path / "s").exists()


SCENE = field_scene(
    {"channels": 1, "gps": True,
     "path": [{"t": 0.0, "position": [20.0, -5.0, 1.0]}, {"t": 100.0, "position": [-20.0, 5.0, 1.0]}]},
    {"start_utc": FIELD_START_UTC, "gps_rate_hz": 1.0}, seed=4, rate_hz=1.0,
)


class AutopilotServer:
    """A TCP MAVLink endpoint (like a SITL's port 5760) streaming one fixed attitude at 50 Hz."""

    def __init__(self, q_ned_frd):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.q = q_ned_frd
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        self.sock.settimeout(10)
        conn, _ = self.sock.accept()
        enc = encoder()
        ms = 0
        with conn:
            while not self.stop.wait(0.02):
                ms += 20
                try:
                    conn.sendall(heartbeat(enc) + att_q(enc, ms, self.q))
                except OSError:
                    return

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.sock.close()


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timing
@pytest.mark.timeout(90)
def test_logged_mavlink_attitude_is_the_exported_receiver_attitude(tmp_path, scene_file):
    scene = scene_file(SCENE, "scene.toml")
    # Yaw 30 deg east of north, pitch 10 deg, as FRD -> NED; our FLU -> ENU is heading 30.
    q_ned = tuple(Rotation.from_euler("ZYX", [30.0, 10.0, 0.0], degrees=True).as_quat(scalar_first=True))
    server = AutopilotServer(q_ned)
    emu = EmulatorProcess("--scene", str(scene), "--port", "pty", "--speed", "10", "--frames", "20",
                          "--delay", "1.5", streams=2)  # fmt: skip
    out = tmp_path / "session"
    try:
        logger = subprocess.Popen(
            [sys.executable, "-m", "bench.cli", "log", "--arva", emu.ports["arva"], "--gps", emu.ports["gps"],
             "--attitude", f"socket://127.0.0.1:{server.port},format=mavlink", "--tx-pose", "1=46.5,8.0,2499.0",
             "--out", str(out), "--duration", "3.5"],  # the 1.5 s delay, 2 s of epochs
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        _, err = logger.communicate(timeout=60)
        assert logger.returncode == 0, err
    finally:
        emu.kill()
        server.close()
    manifest = read_manifest(out)
    dev = manifest["devices"]["attitude-rx"]
    assert dev["format"] == "mavlink" and dev["kind"] == "attitude"
    # No --origin: the first receiver GGA fix became the session's origin, in the manifest.
    first = next(r for r in read_jsonl(out / "gps-rx.jsonl") if r.get("sentence") == "GGA" and r["valid"])
    assert manifest["origin"] == {"lat": first["lat"], "lon": first["lon"], "alt": first["alt_hae"],
                                  "source": "first receiver fix"}  # fmt: skip
    atts = [r for r in read_jsonl(out / "attitude-rx.jsonl") if "q" in r]
    records = list(read_jsonl(out / "attitude-rx.jsonl"))
    errors = [r for r in records if "error" in r]
    # The only flag allowed: a frame torn by the logger's own stop (flushed last).
    assert len(atts) > 50 and errors in ([], [records[-1]]), errors
    assert all(set(e["error"]) == {"fragments", "junk_bytes"} and e["error"]["fragments"] == 1 for e in errors)
    assert [r["time_boot_ms"] for r in atts] == list(range(20, 20 * len(atts) + 1, 20))
    expected = hpr_to_quaternion(30.0, 0.0, 10.0)
    result = export_rows(out)
    assert result.rows > 10  # of 20 (1 s of slack at 10x, as before with 30 and 20)
    cols = result.columns
    q = np.c_[cols["rx_qw"], cols["rx_qx"], cols["rx_qy"], cols["rx_qz"]]
    np.testing.assert_allclose(q, np.broadcast_to(expected, q.shape), atol=1e-6)


@pytest.mark.subprocess
def test_without_the_extra_log_says_install_it_and_creates_nothing(tmp_path):
    from without_extra import run_without

    argv = ["log", "--arva", "loop://", "--attitude", "loop://,format=mavlink", "--out", str(tmp_path / "s")]
    p = run_without("pymavlink", "bench.cli:main", argv)
    assert (p.returncode, p.stdout) == (2, "")
    assert p.stderr == (
        "arva-bench: MAVLink attitude needs pymavlink (install the extra: pip install 'arva-bench[mavlink]')\n"
    )
    assert not (tmp_path / "s").exists()
