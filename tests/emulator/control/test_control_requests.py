"""Control requests (BRIEF 9) parsed and validated like scene values: exact errors,
and no input at all that makes the parser raise anything but ControlError."""

import json
import math
import socket

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.control.requests import (
    MAX_LINE,
    ControlError,
    Fault,
    Pause,
    Quit,
    RemoveTransmitter,
    Resume,
    SetReceiver,
    SetTransmitter,
    Status,
    Step,
    Truth,
    encode_reply,
    parse_request,
)
from emulator.control.server import ControlAddress, check_host, control_address
from emulator.output.net_ports import all_loopback, resolve
from firmware_proto.errors import InputError


@pytest.mark.parametrize(
    "line, expected",
    [
        ('{"op": "status"}', Status()),
        ('{"op": "step"}', Step(1)),
        ('{"op": "step", "n": 25}', Step(25)),
        ('{"op": "pause"}', Pause()),
        ('{"op": "resume"}', Resume()),
        ('{"op": "set_transmitter", "id": 3, "enabled": false}', SetTransmitter(3, enabled=False)),
        (
            '{"op": "set_transmitter", "id": 3, "position": [1, 2.5, -3], "orientation": [2, 0, 0, 0]}',
            SetTransmitter(3, (1.0, 2.5, -3.0), (1.0, 0.0, 0.0, 0.0)),
        ),
        ('{"op": "remove_transmitter", "id": 65535}', RemoveTransmitter(65535)),
        ('{"op": "set_receiver", "position": [0, 0, 1]}', SetReceiver(None, (0.0, 0.0, 1.0))),
        ('{"op": "set_receiver", "id": 7, "path": "resume"}', SetReceiver(7, path="resume")),
        ('{"op": "fault", "kind": "disconnect", "seconds": 2}', Fault("arva", "disconnect", seconds=2.0)),
        ('{"op": "fault", "stream": "gps:rx", "kind": "stall", "ms": 250.5}', Fault("gps:rx", "stall", ms=250.5)),
        ('{"op": "fault", "kind": "corrupt", "bytes": 4}', Fault("arva", "corrupt", count=4)),
        ('{"op": "truth"}', Truth()),
        ('{"op": "quit"}\n', Quit()),
    ],
)
def test_every_request_of_the_table(line, expected):
    assert parse_request(line.encode()) == expected


@pytest.mark.parametrize(
    "line, error",
    [
        (b"", "request is not JSON: input data was truncated"),
        (b"\xff\xfe", "request is not UTF-8 (byte offset 0)"),
        (b"[1, 2]", "request must be a JSON object, got an array"),
        (b'{"n": 1}', 'request has no "op"'),
        (b'{"op": 5}', '"op" must be a string, got an integer'),
        (b'{"op": "jump"}', "unknown op 'jump' (known: status, step, pause, resume, set_transmitter, "
         "remove_transmitter, set_receiver, fault, truth, quit)"),
        (b'{"op": "status", "verbose": true}', "status: unknown key 'verbose'"),
        (b'{"op": "step", "n": 0}', "step.n: must be in 1..1000000, got 0"),
        (b'{"op": "step", "n": 1.5}', "step.n: expected an integer, got a number"),
        (b'{"op": "step", "n": true}', "step.n: expected an integer, got a boolean"),
        (b'{"op": "set_transmitter"}', "set_transmitter.id: missing"),
        (b'{"op": "set_transmitter", "id": 65536}', "set_transmitter.id: must be in 0..65535, got 65536"),
        (b'{"op": "set_transmitter", "id": 1, "position": [1, 2]}',
         "set_transmitter.position: expected 3 numbers [x, y, z] in metres, got 2"),
        (b'{"op": "set_transmitter", "id": 1, "position": [1, "2", 3]}',
         "set_transmitter.position[1]: expected a number, got a string"),
        (b'{"op": "set_transmitter", "id": 1, "position": [1e999, 0, 0]}',
         "set_transmitter.position[0]: must be finite, got inf"),
        (b'{"op": "set_transmitter", "id": 1, "position": [NaN, 0, 0]}', "request is not JSON: invalid character (byte 48)"),
        (b'{"op": "set_transmitter", "id": 1, "orientation": [0, 0, 0, 1e-12]}',
         "set_transmitter.orientation: quaternion norm 1e-12 is below 1e-09"),
        (b'{"op": "set_transmitter", "id": 1, "enabled": 1}', "set_transmitter.enabled: expected true or false, got an integer"),
        (b'{"op": "set_receiver"}', 'set_receiver: give a position and/or an orientation, or path = "resume"'),
        (b'{"op": "set_receiver", "path": "pause"}', 'set_receiver.path: must be "resume", got "pause"'),
        (b'{"op": "set_receiver", "path": "resume", "position": [0, 0, 0]}',
         'set_receiver: give either path = "resume" or a position/orientation, not both'),
        (b'{"op": "fault", "kind": "unplug"}', 'fault.kind: must be one of corrupt, disconnect, stall, got "unplug"'),
        (b'{"op": "fault", "kind": "disconnect"}', "fault.seconds: missing"),
        (b'{"op": "fault", "kind": "disconnect", "seconds": 0}', "fault.seconds: must be within (0, 86400] s, got 0"),
        (b'{"op": "fault", "kind": "stall", "seconds": 1}', "fault.seconds: not a parameter of kind stall (it takes ms)"),
        (b'{"op": "fault", "kind": "corrupt", "bytes": -1}', "fault.bytes: must be in 1..1000000, got -1"),
        (b'{"op": "fault", "stream": 3, "kind": "corrupt", "bytes": 1}',
         "fault.stream: expected a stream label (arva, gps:rx ...), got an integer"),
        (b"{" * 100_000, f"request longer than {MAX_LINE} bytes"),
    ],
)
def test_malformed_and_invalid_requests_get_one_line_errors(line, error):
    with pytest.raises(ControlError) as info:
        parse_request(line)
    assert str(info.value) == error


def test_deep_nesting_and_huge_numbers_are_errors_not_crashes():
    with pytest.raises(ControlError, match="request is not JSON"):
        parse_request(b"[" * 50_000)
    with pytest.raises(ControlError, match="set_transmitter.position.0.: must be finite, got a huge integer"):
        parse_request(b'{"op": "set_transmitter", "id": 1, "position": [1' + b"0" * 400 + b', 0, 0]}')


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=20,
)
ops = st.sampled_from(
    ["status", "step", "pause", "resume", "set_transmitter", "remove_transmitter", "set_receiver", "fault", "truth", "quit"]
)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(op=ops, fields=st.dictionaries(
    st.sampled_from(["id", "n", "position", "orientation", "enabled", "path", "stream", "kind", "seconds", "ms", "bytes", "x"]),
    json_values, max_size=5,
))
def test_any_json_object_is_a_request_or_a_control_error(op, fields):
    line = json.dumps({"op": op, **fields}).encode()
    try:
        req = parse_request(line)
    except ControlError as exc:
        assert "\n" not in str(exc)
        return
    assert req.op == op
    for name in ("position", "orientation"):
        value = getattr(req, name, None)
        if value is not None:
            assert all(math.isfinite(v) for v in value)
    if getattr(req, "orientation", None) is not None:
        assert math.isclose(math.fsum(v * v for v in req.orientation), 1.0, rel_tol=1e-9)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_are_a_request_or_a_control_error(data):
    try:
        parse_request(data)
    except ControlError:
        pass


def test_replies_are_single_json_lines_and_never_nan():
    assert encode_reply({"ok": True, "epoch": 3}) == b'{"ok": true, "epoch": 3}\n'
    with pytest.raises(ValueError):
        encode_reply({"ok": True, "t": math.nan})


@pytest.mark.parametrize(
    "text, address",
    [
        ("unix:/tmp/a.sock", ControlAddress("unix", path="/tmp/a.sock")),
        ("tcp:127.0.0.1:7000", ControlAddress("tcp", host="127.0.0.1", port=7000)),
        ("tcp:[::1]:0", ControlAddress("tcp", host="::1", port=0)),
        ("tcp:localhost:65535", ControlAddress("tcp", host="localhost", port=65535)),
    ],
)
def test_control_addresses(text, address):
    assert control_address(text) == address
    assert str(address) == text


@pytest.mark.parametrize("text", ["unix:", "tcp:127.0.0.1", "tcp:127.0.0.1:65536", "tcp::80", "udp:x:1", "/tmp/s", "unix:/" + "x" * 107])
def test_bad_control_addresses(text):
    with pytest.raises(InputError):
        control_address(text)


def is_loopback(host: str) -> bool:
    """check_host's rule: every address ``host`` resolves to is loopback (False if none)."""
    try:
        return all_loopback(resolve(host, None, host))
    except InputError:
        return False


def test_loopback_check():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("127.3.4.5")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10") and not is_loopback("::")
    assert not is_loopback("a..b")  # (a name IDNA cannot encode: not resolvable, no exception)


def test_a_control_host_that_does_not_resolve_is_named_as_such(monkeypatch):
    """Not "not a loopback address; add --control-any-host", which would not help."""

    def refuse(*_args, **_kwargs):
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", refuse)
    with pytest.raises(InputError) as err:
        check_host(control_address("tcp:nowhere.invalid:7000"), any_host=False)
    assert str(err.value) == (
        "--control tcp:nowhere.invalid:7000: cannot resolve 'nowhere.invalid': Name or service not known"
    )


@pytest.fixture(scope="module")
def echo_server(tmp_path_factory):
    """A ControlServer whose handler echoes the op (no emulator behind it)."""
    from emulator.control.server import ControlServer

    path = tmp_path_factory.mktemp("ctl") / "s.sock"
    server = ControlServer(ControlAddress("unix", path=str(path)), lambda req: {"ok": True, "op": req.op}, lambda: None)
    server.start()
    yield str(path)
    server.close()


@settings(max_examples=60, deadline=None)
@given(chunks=st.lists(st.binary(max_size=40) | st.sampled_from([b'{"op": "status"}\n', b"\n", b'{"op": "tr', b'uth"}\n']),
                       max_size=12))
def test_exactly_one_reply_per_non_blank_line_however_the_bytes_are_cut(echo_server, chunks):
    import socket as _socket

    data = b"".join(chunks) + b'\n{"op": "quit"}\n'
    lines = data.split(b"\n")[:-1]
    expected = [line for line in lines if line.strip()]
    s = _socket.socket(_socket.AF_UNIX)
    s.settimeout(10)
    s.connect(echo_server)
    try:
        for chunk in [*chunks, b'\n{"op": "quit"}\n']:
            s.sendall(chunk)
        got = b""
        while got.count(b"\n") < len(expected):
            part = s.recv(65536)
            assert part, "server closed the connection"
            got += part
        replies = [json.loads(line) for line in got.split(b"\n")[:-1]]
    finally:
        s.close()
    assert len(replies) == len(expected)
    for line, reply in zip(expected, replies):
        try:
            req = parse_request(line)
        except ControlError as exc:
            assert reply == {"ok": False, "error": " ".join(str(exc).split())}
        else:
            assert reply == {"ok": True, "op": req.op}
