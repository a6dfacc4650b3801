"""Corrupt and foreign sessions: every reader (export, fit, replay, dash) exits 2 with one
exact line naming the file and the problem; never a traceback. The corpus is generated
here, one small session per case."""

from __future__ import annotations

import base64
import json
import os

import pytest

from bench.cli import main
from bench.session import MAX_RAW_LINE, SessionWriter
from firmware_proto.sentences import encode_parva

PASHR = b"$PASHR,080000.000,123.40,T,+01.50,-02.00,+00.00,0.050,0.050,0.100,1,1*06\r\n"


def good_session(path):
    w = SessionWriter(path, {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"},
                                         "attitude-rx": {"kind": "attitude", "url": "y", "role": "rx"}},
                             "origin": {"lat": 46.5, "lon": 8.0, "alt": 2500.0},
                             "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2500.0}}})  # fmt: skip
    w.raw("arva", encode_parva(0, 1, 1, 1, 1905, 21), mono=50.0, utc=1.7e9)
    w.raw("attitude-rx", PASHR, mono=50.05, utc=1.7e9)
    w.close()


def set_manifest(path, text: bytes):
    (path / "manifest.json").write_bytes(text)


def edit_manifest(path, edit):
    m = json.loads((path / "manifest.json").read_text())
    edit(m)
    set_manifest(path, json.dumps(m).encode())


def _kind(m):
    m["devices"]["attitude-rx"]["kind"] = "radar"


def _no_lon(m):
    del m["tx_poses"]["1"]["lon"]


def _origin_text(m):
    m["origin"] = "46.5,8.0"


def _future(m):
    m["version"] = 99


def _escape(m):
    m["devices"]["../etc"] = m["devices"].pop("attitude-rx")


def _raw_dir(path):
    (path / "attitude-rx.raw").unlink()
    (path / "attitude-rx.raw").mkdir()


def _raw_middle(path):
    with open(path / "arva.raw", "ab") as f:
        f.write(b"not a read\n12.0\t2027-01-15T08:00:00.250000Z\tJA==\n")


def _raw_loop(path):
    (path / "arva.raw").unlink()
    (path / "arva.raw").symlink_to("arva.raw")  # a link to itself


def _raw_dangling(path):
    (path / "arva.raw").unlink()
    (path / "arva.raw").symlink_to("gone.raw")


def _nested(depth: int):
    value: object = 0
    for _ in range(depth - 1):  # the manifest's own object is the first level
        value = {"a": value}
    return value


def _no_devices(m):
    m["devices"] = {}


def _arva_line(mono: bytes, utc: bytes = b"2023-11-14T22:13:21.000000Z"):
    """Append a read of the next epoch to arva.raw with these stamps (the first read is at
    mono 50.0, 2023-11-14T22:13:20Z)."""
    b64 = base64.b64encode(encode_parva(1, 1, 1, 1, 1905, 21))

    def corrupt(path):
        with open(path / "arva.raw", "ab") as f:
            f.write(mono + b"\t" + utc + b"\t" + b64 + b"\n")

    return corrupt


A = "{d}/arva.raw: line 2: "
CASES = {
    # issue 29, item 7: stamps that are not finite, go back, or leave the session's span
    "stamp-nan": (_arva_line(b"nan"), A + "stamp nan: not a finite number of seconds"),
    "stamp-inf": (_arva_line(b"inf"), A + "stamp inf: not a finite number of seconds"),
    "stamp-1e308": (_arva_line(b"1e308"), A + "stamp 1e+308 runs 1e+308 s ahead of the wall time since the session's "
                                              "first read (more than 60 s)"),
    "stamp-goes-back": (_arva_line(b"40.0"), A + "stamp 40.0 goes back 10 s (more than 0.001 s)"),
    "stamp-year-9999": (_arva_line(b"51.0", b"9999-01-01T00:00:00.000000Z"),
                        A + "wall time 9999-01-01T00:00:00.000000Z is 2.51671e+11 s from the session's first read "
                            "(outside -60 .. 3.1536e+07 s)"),
    "stamp-before-start": (_arva_line(b"51.0", b"2023-11-14T20:00:00.000000Z"),
                           A + "wall time 2023-11-14T20:00:00.000000Z is -8000 s from the session's first read "
                               "(outside -60 .. 3.1536e+07 s)"),
}
def _link_to(name: str, target: str):
    def corrupt(path):
        (path / name).unlink()
        (path / name).symlink_to(target)

    return corrupt


def _fifo(path):
    (path / "arva.raw").unlink()
    os.mkfifo(path / "arva.raw")


def _raw_line_too_long(path):
    with open(path / "arva.raw", "ab") as f:
        f.write(b"51.0\t2023-11-14T22:13:21.000000Z\t" + b"JCQk" * (MAX_RAW_LINE // 4))


NOT_REGULAR = "a {kind}, not a regular file: only regular files are read as a {what}"
M = "{d}/manifest.json"
CASES |= {
    # issue 29, item 4: endless or blocking files, and lines or files above the readers' caps
    "raw-is-dev-zero": (_link_to("arva.raw", "/dev/zero"),
                        "{d}/arva.raw: " + NOT_REGULAR.format(kind="character device", what="log file")),
    "raw-is-a-fifo": (_fifo, "{d}/arva.raw: " + NOT_REGULAR.format(kind="named pipe", what="log file")),
    "manifest-is-dev-zero": (_link_to("manifest.json", "/dev/zero"),
                             M + ": " + NOT_REGULAR.format(kind="character device", what="manifest file")),
    "raw-line-too-long": (_raw_line_too_long, f"{{d}}/arva.raw: line 2: longer than {MAX_RAW_LINE} bytes (not a raw log line)"),
    "manifest-too-large": (lambda p: set_manifest(p, b'{"format": "arva-session", "note": "' + b"x" * (1 << 20) + b'"}'),
                           M + ": larger than 1048576 bytes: not a manifest file"),
}
CASES |= {
    # issue 29, item 5: nesting that exhausts the JSON parser's recursion, or just deep
    "manifest-5000-deep": (lambda p: set_manifest(p, b'{"format": "arva-session", "x": ' + b"[" * 5000 + b"]" * 5000 + b"}"),
                           M + ": JSON nested more than 32 deep"),
    "manifest-40-deep": (lambda p: edit_manifest(p, lambda m: m.update(note=_nested(40))), M + ": JSON nested more than 32 deep"),
}
CASES |= {
    # issue 29, item 9: a log that cannot be looked at, a manifest that lists nothing
    "raw-symlink-loop": (_raw_loop, "{d}/arva.raw: unreadable: Too many levels of symbolic links"),
    "raw-dangling-symlink": (_raw_dangling, "{d}/arva.raw: a symbolic link to nothing (gone.raw)"),
    "no-devices": (lambda p: edit_manifest(p, _no_devices), M + ": devices: none listed (a session logs at least one device)"),
    "non-utf8": (lambda p: set_manifest(p, b'{"format": "arva-session", "note": "\xff"}'),
                 M + ": not UTF-8 text (byte 36)"),
    "json-list": (lambda p: set_manifest(p, b"[1, 2]"), M + ": not a session manifest (a JSON object), got an array"),
    "not-json": (lambda p: set_manifest(p, b'{"format": '), M + ": not JSON (line 1 column 12: Expecting value)"),
    "foreign": (lambda p: set_manifest(p, b'{"format": "other"}'), M + ": not an arva-session manifest"),
    "future": (lambda p: edit_manifest(p, _future), M + ": session format 99 is newer than this program reads (2)"),
    "origin-string": (lambda p: edit_manifest(p, _origin_text), M + ": origin: expected an object, got a string"),
    "tx-pose-no-lon": (lambda p: edit_manifest(p, _no_lon), M + ": tx_poses.1.lon: missing"),
    "unknown-kind": (lambda p: edit_manifest(p, _kind),
                     M + ': devices.attitude-rx.kind: must be one of arva, attitude, gps, got "radar"'),
    "device-not-an-object": (lambda p: edit_manifest(p, lambda m: m["devices"].update(arva=5)),
                             M + ": devices.arva: expected an object, got an integer"),
    "device-name-escapes": (lambda p: edit_manifest(p, _escape),
                            M + ": devices.../etc: '../etc' is not a device name (it names a file in the session)"),
    "raw-is-a-directory": (_raw_dir, "{d}/attitude-rx.raw: a directory, not a log file"),
    "raw-bad-line": (_raw_middle, "{d}/arva.raw: line 2: not a raw record (not enough values to unpack (expected 3, got 1))"),
}  # fmt: skip

READERS = {
    "export": lambda d, tmp: ["export", str(d), "--csv", str(tmp / "out.csv")],
    "replay": lambda d, tmp: ["replay", str(d), "--speed", "0"],
    "dash": lambda d, tmp: ["dash", str(d)],
    "fit": lambda d, tmp: ["fit", str(d)],
}


def assert_one_line(tmp_path, capsys, corrupt, expected: str, reader: str) -> None:
    """The good session, corrupted, read by ``reader``: exit 2 and the one line expected."""
    d = tmp_path / "s"
    good_session(d)
    corrupt(d)
    code = main(READERS[reader](d, tmp_path))
    line = expected.format(d=d)
    if reader == "fit":  # the fit names its input argument first
        line = f"fit: {d}: {line}"
    assert (code, capsys.readouterr().err) == (2, f"arva-bench: {line}\n")


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_a_corrupt_session_is_one_line_and_exit_2(tmp_path, capsys, case, reader):
    assert_one_line(tmp_path, capsys, *CASES[case], reader)


def test_a_receiver_log_that_decodes_to_nothing_is_an_error(tmp_path, capsys):
    d = tmp_path / "s"
    w = SessionWriter(d, {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx"}},
                          "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2500.0}}})  # fmt: skip
    w.raw("arva", PASHR, mono=50.0, utc=1.7e9)  # an attitude unit plugged in as the receiver
    w.close()
    assert main(["export", str(d), "--csv", str(tmp_path / "out.csv")]) == 2
    assert capsys.readouterr().err == (
        f"arva-bench: {d}/arva.raw: {len(PASHR)} bytes decode to no $PARVA epoch (is arva an ARVA receiver?)\n"
    )


def test_the_good_session_exports(tmp_path, capsys):
    good_session(tmp_path / "s")
    assert main(["export", str(tmp_path / "s"), "--csv", str(tmp_path / "out.csv")]) == 0


def _only_attitude(m):
    del m["devices"]["arva"]


#: Sessions that are valid but hold nothing to export (issue 29, item 9): export and fit
#: refuse them (one line, exit 2) instead of writing "0 rows ... dropped: none".
NOTHING_TO_EXPORT = {
    "receiver-log-missing": (lambda p: (p / "arva.raw").unlink(), "{d}: no receiver log (arva.raw: missing): nothing to export"),
    "receiver-log-empty": (lambda p: (p / "arva.raw").write_bytes(b""),
                           "{d}/arva.raw: no complete read (empty or only a torn line): nothing to export"),
    "receiver-log-torn": (lambda p: (p / "arva.raw").write_bytes(b"50.0\t2023-11-14T22:13:20.000000Z\tJFBBUl"),
                          "{d}/arva.raw: no complete read (empty or only a torn line): nothing to export"),
    "no-receiver": (lambda p: edit_manifest(p, _only_attitude), M + ": no receiver (a device of kind arva): nothing to export"),
}  # fmt: skip


@pytest.mark.parametrize("reader", ["export", "fit"])
@pytest.mark.parametrize("case", sorted(NOTHING_TO_EXPORT))
def test_a_session_with_nothing_to_export_is_refused(tmp_path, capsys, case, reader):
    assert_one_line(tmp_path, capsys, *NOTHING_TO_EXPORT[case], reader)
    assert not (tmp_path / "out.csv").exists()


def test_replay_in_real_time_refuses_a_stamp_far_ahead_before_waiting(tmp_path, capsys):
    """The issue's case: ``replay --speed 1`` waited for ever (or overflowed after 14 s)."""
    d = tmp_path / "s"
    good_session(d)
    _arva_line(b"1e308")(d)
    assert main(["replay", str(d), "--speed", "1", "--port", "pty"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"arva-bench: {d}/arva.raw: line 2: stamp 1e+308 runs") and err.count("\n") == 1
