"""MAVLink ride-along with a real autopilot's habits: ArduPilot streams ATTITUDE (Euler)
rather than ATTITUDE_QUATERNION, streams only to peers that send HEARTBEATs, and streams
what SET_MESSAGE_INTERVAL asks for. pymavlink-encoded messages over UDP loopback."""

import logging
import math
import time

import pytest

pytest.importorskip("pymavlink")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

from emulator.closed_loop.mavlink import (  # noqa: E402
    MAV_CMD_SET_MESSAGE_INTERVAL,
    WARN_AFTER_S,
    MavlinkPoseSource,
    frd_ned_to_flu_enu,
)
from emulator.pipeline import scene_streams  # noqa: E402
from mavlink_helpers import free_udp_port, ned_quaternion  # noqa: E402
from scene_builders import external_mavlink_text  # noqa: E402
from emulator.receiver.model import measure_one  # noqa: E402
from emulator.scene.reader import loads_scene  # noqa: E402
from firmware_proto.sentences import encode_parva  # noqa: E402


def decoded(*encoded):
    """Messages as they come off a link: packed by pymavlink, parsed back."""
    tx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    rx = mavlink2.MAVLink(None)
    data = b"".join(m.pack(tx) for m in encoded)
    return rx.parse_buffer(data)


MAV = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


def position(boot_ms, north=0.0, east=0.0, down=0.0):
    return MAV.local_position_ned_encode(boot_ms, north, east, down, 0.0, 0.0, 0.0)


def attitude(boot_ms, yaw_deg, pitch_deg=0.0, roll_deg=0.0):
    return MAV.attitude_encode(boot_ms, *(math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg)), 0.0, 0.0, 0.0)


def test_attitude_euler_is_taken_like_the_quaternion():
    src = MavlinkPoseSource("unused")
    for i, msg in enumerate(decoded(position(5, 1.0, 2.0, -3.0), attitude(5, 30.0, 10.0, -20.0))):
        src.handle(msg, 100.0 + i)
    pose = src.latest()
    assert pose.position == (2.0, 1.0, 3.0)
    expected = frd_ned_to_flu_enu(ned_quaternion(30.0, 10.0, -20.0))
    assert pose.orientation == pytest.approx(expected, abs=1e-6)  # float32 angles on the wire
    assert src.counts == {"LOCAL_POSITION_NED": 1, "ATTITUDE_QUATERNION": 0, "ATTITUDE": 1}


def test_once_a_quaternion_came_attitude_euler_is_ignored():
    src = MavlinkPoseSource("unused")
    q = ned_quaternion(90.0)
    msgs = decoded(
        position(1),
        MAV.attitude_quaternion_encode(1, *q, 0.0, 0.0, 0.0),
        attitude(1, 0.0),  # a different heading: must not win
    )
    for msg in msgs:
        src.handle(msg, 1.0)
    assert src.latest().orientation == pytest.approx(frd_ned_to_flu_enu(q), abs=1e-7)
    assert src.counts == {"LOCAL_POSITION_NED": 1, "ATTITUDE_QUATERNION": 1}


@pytest.mark.parametrize(
    "make, text",
    [
        (
            lambda k: position(k),
            "x: LOCAL_POSITION_NED arrives but no ATTITUDE_QUATERNION or ATTITUDE: epochs stay at the start pose "
            "(enable an attitude stream on the autopilot)",
        ),
        (
            lambda k: attitude(k, 10.0),
            "x: attitude arrives but no LOCAL_POSITION_NED: epochs stay at the start pose "
            "(does the autopilot have a position estimate?)",
        ),
    ],
)
def test_half_a_pose_is_warned_about_once(make, text, caplog):
    src = MavlinkPoseSource("x")
    with caplog.at_level(logging.WARNING, logger="arva-emulate"):
        for k in range(10):  # one message every 0.5 s for 4.5 s
            (msg,) = decoded(make(k))
            src.handle(msg, 10.0 + 0.5 * k)
            if 0.5 * k < WARN_AFTER_S:
                assert caplog.records == []
    assert [r.getMessage() for r in caplog.records] == [text]
    assert src.warned == text


def test_no_warning_when_both_halves_arrive(caplog):
    src = MavlinkPoseSource("x")
    with caplog.at_level(logging.WARNING, logger="arva-emulate"):
        for k in range(10):
            for msg in decoded(position(k), attitude(k, 0.0)):
                src.handle(msg, 0.5 * k)
    assert caplog.records == [] and src.warned is None


@pytest.mark.slow
def test_an_ardupilot_like_autopilot_is_greeted_asked_and_ridden():
    port = free_udp_port()
    stream = scene_streams(loads_scene(external_mavlink_text(port), "ext.toml"))[0]
    src = stream.receiver.pose_source.start()
    ap = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    try:
        # The autopilot announces itself (1 Hz, as autopilots do); the emulator answers
        # with a GCS heartbeat and asks for LOCAL_POSITION_NED (32) and
        # ATTITUDE_QUATERNION (31) at 20 Hz.
        ours, asked = None, set()
        end = time.monotonic() + 10.0
        while (ours is None or asked != {31.0, 32.0}) and time.monotonic() < end:
            ap.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
            t_next = time.monotonic() + 1.0
            while time.monotonic() < t_next:
                msg = ap.recv_match(type=["HEARTBEAT", "COMMAND_LONG"], blocking=True, timeout=0.1)
                if msg is None:
                    continue
                if msg.get_type() == "HEARTBEAT":
                    ours = msg
                else:
                    assert (msg.command, msg.target_system, msg.target_component) == (MAV_CMD_SET_MESSAGE_INTERVAL, 1, 1)
                    assert msg.param2 == 50000.0  # microseconds: 20 Hz
                    asked.add(msg.param1)
        assert (ours.type, ours.autopilot) == (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID)
        assert asked == {31.0, 32.0}
        # ArduPilot's default streams: position and ATTITUDE (Euler), no quaternion.
        ap.mav.local_position_ned_send(9, 4.0, 3.0, 0.0, 0.0, 0.0, 0.0)
        ap.mav.attitude_send(9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # facing north
        src.wait(5.0)
        d, delta = measure_one([8.0, 4.0, 0.0], [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], [15.0, 0.0, 0.0])
        assert stream.render(0, 1) == encode_parva(0, 1, 1, 1, d, delta)
        assert src.heartbeats >= 1 and src.requests >= 2
    finally:
        ap.close()
        stream.close()
