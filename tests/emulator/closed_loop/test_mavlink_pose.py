"""MAVLink pose input: frame conversions, and real pymavlink-encoded messages over UDP
loopback and a serial line (a pty) into the closed-loop receiver."""

import math
import os
import socket
import time
import tomllib
import tty

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("pymavlink")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

from emulator.closed_loop.mavlink import MavlinkPoseSource, Pose, frd_ned_to_flu_enu, ned_to_enu  # noqa: E402
from emulator.receiver.model import measure_one  # noqa: E402
from emulator.scene.reader import loads_scene  # noqa: E402
from emulator.pipeline import scene_streams  # noqa: E402
from mavlink_helpers import free_udp_port, ned_quaternion  # noqa: E402
from scene_builders import external_mavlink_text  # noqa: E402
from firmware_proto.sentences import encode_parva  # noqa: E402

T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED -> ENU
F = np.diag([1.0, -1.0, -1.0])  # FLU -> FRD


# --------------------------------------------------------------------------- frames
def test_ned_to_enu():
    assert ned_to_enu((1.0, 2.0, -3.0)) == (2.0, 1.0, 3.0)


@pytest.mark.parametrize(
    "yaw, expected",
    [
        (0.0, (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))),  # facing north = ENU yaw 90
        (90.0, (1.0, 0.0, 0.0, 0.0)),  # facing east = ENU identity
        (180.0, (math.sqrt(0.5), 0.0, 0.0, -math.sqrt(0.5))),  # south = ENU yaw -90
    ],
)
def test_headings(yaw, expected):
    assert frd_ned_to_flu_enu(ned_quaternion(yaw)) == pytest.approx(expected, abs=1e-12)


def test_quaternion_is_T_R_F_for_any_attitude():
    rng = np.random.default_rng(5)
    for q in rng.standard_normal((200, 4)):
        q /= np.linalg.norm(q)
        r_ned_frd = Rotation.from_quat(q, scalar_first=True).as_matrix()
        ours = Rotation.from_quat(frd_ned_to_flu_enu(q), scalar_first=True).as_matrix()
        assert np.allclose(ours, T @ r_ned_frd @ F, atol=1e-12)


def test_roll_right_wing_down_lifts_the_left_axis():
    r = Rotation.from_quat(frd_ned_to_flu_enu(ned_quaternion(90.0, 0.0, 30.0)), scalar_first=True).as_matrix()
    assert r[:, 0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)  # still facing east
    assert r[:, 1] == pytest.approx([0.0, math.cos(math.radians(30)), math.sin(math.radians(30))], abs=1e-12)


def test_degenerate_quaternion_is_rejected():
    with pytest.raises(ValueError, match="degenerate"):
        frd_ned_to_flu_enu((0.0, 0.0, 0.0, 0.0))


def test_extrapolation_is_bounded():
    p = Pose((1.0, 2.0, 3.0), (1.0, 0.0, -2.0), (1, 0, 0, 0), t_position=100.0, time_boot_ms=0)
    assert p.extrapolated(100.5) == (1.5, 2.0, 2.0)
    assert p.extrapolated(99.0) == (1.0, 2.0, 3.0)  # never backwards
    assert p.extrapolated(300.0, horizon=1.0) == (2.0, 2.0, 1.0)  # a stale stream is held


# --------------------------------------------------------------------------- UDP loopback
@pytest.fixture
def udp():
    port = free_udp_port()
    src = MavlinkPoseSource(f"udpin:127.0.0.1:{port}", origin=(100.0, 200.0, 10.0)).start()
    out = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
    yield port, src, out
    out.close()
    src.close()


def send_pose(conn, north, east, down, yaw_deg, boot_ms=1000, v=(0.0, 0.0, 0.0)):
    conn.mav.local_position_ned_send(boot_ms, north, east, down, *v)
    conn.mav.attitude_quaternion_send(boot_ms, *ned_quaternion(yaw_deg), 0.0, 0.0, 0.0)


def wait_for(src, boot_ms, attitudes=1, timeout=5.0):
    """The pose of ``boot_ms`` once ``attitudes`` ATTITUDE_QUATERNIONs have been taken (the
    position and the attitude are two messages: the second pose's attitude may come later)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        pose = src.latest()
        taken = src.counts["ATTITUDE_QUATERNION"]
        if pose is not None and pose.time_boot_ms == boot_ms and taken >= attitudes:
            return pose
        time.sleep(0.005)
    raise TimeoutError(f"no pose with time_boot_ms {boot_ms}")


def test_pose_over_udp(udp):
    _, src, out = udp
    assert src.latest() is None
    send_pose(out, 3.0, 4.0, -5.0, 0.0, v=(1.0, 2.0, 0.5))
    pose = src.wait(5.0)
    assert pose.position == (104.0, 203.0, 15.0)  # origin + (east, north, up)
    assert pose.velocity == (2.0, 1.0, -0.5)
    assert pose.orientation == pytest.approx((math.sqrt(0.5), 0, 0, math.sqrt(0.5)), abs=1e-7)  # float32 on the wire
    assert src.counts == {"LOCAL_POSITION_NED": 1, "ATTITUDE_QUATERNION": 1}


def test_garbage_on_the_link_is_survived(udp):
    port, src, out = udp
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    junk.sendto(b"\xfd\x09\x00\x00garbage" + bytes(range(40)), ("127.0.0.1", port))
    junk.close()
    send_pose(out, 1.0, 0.0, 0.0, 90.0, boot_ms=7)
    assert wait_for(src, 7).position == (100.0, 201.0, 10.0)


def test_wait_times_out_on_a_silent_link():
    src = MavlinkPoseSource(f"udpin:127.0.0.1:{free_udp_port()}").start()
    try:
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match="no LOCAL_POSITION_NED"):
            src.wait(0.3)
        assert time.monotonic() - t0 < 2.0
    finally:
        t0 = time.monotonic()
        src.close()
        assert time.monotonic() - t0 < 1.0  # reads block at most 0.2 s


def test_receiver_rides_along_the_autopilot():
    port = free_udp_port()
    scene = loads_scene(external_mavlink_text(port), "ext.toml")
    stream = scene_streams(scene)[0]
    src = stream.receiver.pose_source.start()
    out = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
    try:
        # Facing east at the local origin = ENU (5, 0, 0): 10 m on the dipole axis.
        send_pose(out, 0.0, 0.0, 0.0, 90.0, boot_ms=1)
        wait_for(src, 1)
        assert stream.render(0, 1) == encode_parva(0, 1, 1, 1, 917, 0)
        # 4 m north and 3 m east of the origin, facing north: what the model says there.
        send_pose(out, 4.0, 3.0, 0.0, 0.0, boot_ms=2)
        wait_for(src, 2, attitudes=2)
        d, delta = measure_one([8.0, 4.0, 0.0], [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], [15.0, 0.0, 0.0])
        assert stream.render(1, 1) == encode_parva(1, 1, 1, 1, d, delta)
    finally:
        out.close()
        stream.receiver.close()


def test_before_any_message_epochs_use_the_start_pose():
    scene = loads_scene(external_mavlink_text(free_udp_port()), "ext.toml")
    stream = scene_streams(scene)[0]
    try:
        # The vehicle's start pose: (0, 0) at r_s = 1 m, yaw 0 -> 15.03 m from the dipole.
        d, delta = measure_one([0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [15.0, 0.0, 0.0])
        assert stream.render(0, 1) == encode_parva(0, 1, 1, 1, d, delta)
    finally:
        stream.receiver.close()


# --------------------------------------------------------------------------- serial
@pytest.mark.pty
def test_pose_over_a_serial_line():
    """A telemetry radio on a serial port: pymavlink reads our pty's slave side."""
    master, slave = os.openpty()
    tty.setraw(slave)
    src = MavlinkPoseSource(os.ttyname(slave), baud=57600).start()
    try:
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        data = mav.local_position_ned_encode(42, 10.0, -2.0, -1.0, 0.0, 0.0, 0.0).pack(mav)
        data += mav.attitude_quaternion_encode(42, *ned_quaternion(45.0), 0.0, 0.0, 0.0).pack(mav)
        os.write(master, data)
        pose = src.wait(5.0)
        assert pose.position == (-2.0, 10.0, 1.0) and pose.time_boot_ms == 42
        heading = math.degrees(2 * math.atan2(pose.orientation[3], pose.orientation[0]))
        assert heading == pytest.approx(45.0, abs=1e-5)  # NED 45 (north-east) = ENU 45
    finally:
        src.close()
        os.close(master)
        os.close(slave)


@pytest.mark.subprocess
def test_without_the_extra_the_emulator_says_install_it(tmp_path):
    from without_extra import run_without

    scene = tmp_path / "ext.toml"
    scene.write_text(external_mavlink_text(free_udp_port()))
    p = run_without("pymavlink", "emulator.cli:main", ["--scene", str(scene), "--port", "-", "--frames", "2", "--speed", "0"])
    assert (p.returncode, p.stdout) == (2, "")
    assert p.stderr.splitlines()[-1] == (
        "arva-emulate: MAVLink pose input needs pymavlink (install the extra: pip install 'arva-bench[mavlink]')"
    )


def test_serial_link_baud_comes_from_the_scene():
    from firmware_proto.errors import SceneError

    scene = loads_scene(external_mavlink_text(14551) + "mavlink_baud = 921600\n", "ext.toml")
    stream = scene_streams(scene)[0]
    assert stream.receiver.pose_source.baud == 921600
    assert loads_scene(external_mavlink_text(14551), "ext.toml").receivers[0].vehicle.mavlink_baud == 57600
    with pytest.raises(SceneError, match=r"ext.toml: receiver.vehicle.mavlink_baud: must be in 50..12000000, got 7$"):
        loads_scene(external_mavlink_text(14551) + "mavlink_baud = 7\n", "ext.toml")
    flux = external_mavlink_text(14551).replace('"external_mavlink"', '"flux"').split("mavlink = ")[0]
    with pytest.raises(SceneError, match=r'receiver.vehicle.mavlink_baud: only with controller = "external_mavlink"$'):
        loads_scene(flux + "mavlink_baud = 9600\n", "ext.toml")


@pytest.mark.subprocess
@pytest.mark.pty
def test_truth_reports_the_mavlink_pose_the_stream_uses(arva_emulator):
    """Issue 29: ``truth`` reported the start pose of a receiver driven by MAVLink while
    its epochs used the autopilot's pose."""
    port = free_udp_port()
    emu = arva_emulator(scene=tomllib.loads(external_mavlink_text(port)), clock="step")
    start = emu.truth()["receivers"][0]
    assert start["position"] == [0.0, 0.0, 1.0]  # the vehicle's start pose, before any message
    assert emu.step(1) == 1  # the first epoch opens the link
    out = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
    try:
        deadline = time.monotonic() + 10
        while True:  # resent until the emulator has it (udp: the link opened with epoch 0)
            send_pose(out, 4.0, 3.0, 0.0, 0.0, boot_ms=2)
            rx = emu.truth()["receivers"][0]
            if rx["position"] != start["position"]:
                break
            assert time.monotonic() < deadline, "truth never showed the MAVLink pose"
            time.sleep(0.05)
    finally:
        out.close()
    # 4 m north, 3 m east of the origin (5, 0, 0), at rest, facing north (float32 on the wire).
    assert rx["position"] == [8.0, 4.0, 0.0]
    assert rx["orientation"] == pytest.approx([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], abs=1e-7)
    # ... and the stream's next epoch is the model's reading at that pose.
    with emu.open(timeout=5) as ser:
        emu.step(1)
        d, delta = measure_one(rx["position"], rx["orientation"], [15.0, 0.0, 0.0])
        assert ser.read_until(b"\r\n") == encode_parva(1, 1, 1, 1, d, delta)
