"""The crash-safe session writer and its readers."""

import base64
import errno
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bench.session import SessionWriter, read_jsonl, read_manifest, read_raw
from firmware_proto.errors import InputError, LinkError


def test_layout_and_exact_lines(tmp_path):
    w = SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "loop://"}}})
    w.raw("arva", b"$PARVA,0,1,1,-1,-1,-1*78\r\n", mono=12.5, utc=1_800_000_000.25)
    w.record("arva", {"seq": 0, "complete": True, "slots": [[-1, -1, -1]]})
    w.close(epochs=1)
    raw = (tmp_path / "s" / "arva.raw").read_bytes()
    b64 = base64.b64encode(b"$PARVA,0,1,1,-1,-1,-1*78\r\n")
    assert raw == b"12.500000\t2027-01-15T08:00:00.250000Z\t" + b64 + b"\n"
    assert (tmp_path / "s" / "arva.jsonl").read_bytes() == b'{"seq":0,"complete":true,"slots":[[-1,-1,-1]]}\n'
    events = list(read_jsonl(tmp_path / "s" / "events.jsonl"))
    assert [e["event"] for e in events] == ["start", "stop"] and events[1]["epochs"] == 1
    m = read_manifest(tmp_path / "s")
    assert m["format"] == "arva-session" and m["version"] == 2  # 2: records stamped by the stamp rule
    assert m["devices"] == {"arva": {"kind": "arva", "url": "loop://"}} and m["summary"] == {"epochs": 1}
    assert m["start_utc"] <= m["stop_utc"]
    assert read_raw(tmp_path / "s" / "arva.raw").reads[0].data == b"$PARVA,0,1,1,-1,-1,-1*78\r\n"


def test_never_overwrites_a_session(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "x").write_text("keep me")
    with pytest.raises(InputError, match=r"s: not empty; a session never overwrites another \(choose a new --out\)$"):
        SessionWriter(tmp_path / "s", {})
    assert (tmp_path / "s" / "x").read_text() == "keep me"


def test_torn_tail_is_tolerated(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    for i in range(5):
        w.raw("gps", b"line %d\r\n" % i, mono=float(i), utc=0.0)
    w.record("gps", {"n": 1})
    w.close()
    raw = tmp_path / "s" / "gps.raw"
    with open(raw, "ab") as f:
        f.write(b"5.000000\t1970-01-01T00:00:00.000000Z\tbGlu")  # SIGKILL mid-line
    got = read_raw(raw)
    assert [r.data for r in got.reads] == [b"line %d\r\n" % i for i in range(5)] and got.torn_tail
    with open(tmp_path / "s" / "gps.jsonl", "ab") as f:
        f.write(b'{"n": 2')
    assert list(read_jsonl(tmp_path / "s" / "gps.jsonl")) == [{"n": 1}]


def test_zero_filled_tail_after_power_cut_is_torn_not_an_error(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    w.raw("arva", b"abc", mono=1.0, utc=0.0)
    w.close()
    with open(tmp_path / "s" / "arva.raw", "ab") as f:
        f.write(b"\x00" * 100 + b"\n")
    got = read_raw(tmp_path / "s" / "arva.raw")
    assert [r.data for r in got.reads] == [b"abc"] and got.torn_tail


def test_corrupt_line_in_the_middle_is_an_error(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    w.raw("arva", b"abc", mono=1.0, utc=0.0)
    w.raw("arva", b"def", mono=2.0, utc=0.0)
    w.close()
    path = tmp_path / "s" / "arva.raw"
    lines = path.read_bytes().split(b"\n")
    path.write_bytes(b"garbage\n" + lines[0] + b"\n" + lines[1] + b"\n")
    with pytest.raises(InputError, match=r"arva.raw: line 1: not a raw record"):
        read_raw(path)


def test_disk_full_is_one_clear_error_and_keeps_what_was_written(tmp_path, monkeypatch):
    w = SessionWriter(tmp_path / "s", {})
    w.raw("arva", b"first", mono=1.0, utc=0.0)
    f = w._file("arva.raw")

    class Full:
        def write(self, _):
            raise OSError(errno.ENOSPC, "No space left on device")

        def fileno(self):
            return f._f.fileno()

    real = f._f
    f._f = Full()
    with pytest.raises(LinkError, match=r"arva.raw: write failed: No space left on device$"):
        w.raw("arva", b"second", mono=2.0, utc=0.0)
    f._f = real
    w.close()
    assert [r.data for r in read_raw(tmp_path / "s" / "arva.raw").reads] == [b"first"]
    assert isinstance(LinkError("x"), OSError)


def test_short_writes_are_completed_and_a_torn_line_stays_the_tail(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    w.raw("arva", b"first", mono=1.0, utc=0.0)
    f = w._file("arva.raw")
    real = f._f

    class Filling:
        """Takes 7 bytes per call, twice, then the disk is full."""

        calls = 0

        def write(self, data):
            self.calls += 1
            if self.calls > 2:
                raise OSError(errno.ENOSPC, "No space left on device")
            return real.write(bytes(data[:7]))

        def fileno(self):
            return real.fileno()

    f._f = Filling()
    with pytest.raises(LinkError, match=r"arva.raw: write failed: No space left on device$"):
        w.raw("arva", b"second", mono=2.0, utc=0.0)
    f._f = real  # the disk has room again, but this file has a torn line: no more appends
    with pytest.raises(LinkError, match=r"arva.raw: write failed: an earlier line was cut short"):
        w.raw("arva", b"third", mono=3.0, utc=0.0)
    w.raw("gps-rx", b"other files go on", mono=3.0, utc=0.0)
    w.close()
    raw = read_raw(tmp_path / "s" / "arva.raw")
    assert [r.data for r in raw.reads] == [b"first"] and raw.torn_tail
    assert (tmp_path / "s" / "arva.raw").read_bytes().count(b"\n") == 1  # 14 torn bytes after it
    assert f.bytes == len((tmp_path / "s" / "arva.raw").read_bytes())

    # A write that returns 0 (no progress, no error) is a full disk too, not a busy loop.
    w2 = SessionWriter(tmp_path / "s2", {})
    g = w2._file("arva.raw")

    class Zero:
        def write(self, data):
            return 0

        def fileno(self):
            return g._f.fileno()

    real2, g._f = g._f, Zero()
    with pytest.raises(LinkError, match=r"short write: no space left on device$"):
        w2.raw("arva", b"x", mono=1.0, utc=0.0)
    g._f = real2
    w2.raw("arva", b"y", mono=2.0, utc=0.0)  # nothing was written: the file is not torn
    w2.close()
    assert [r.data for r in read_raw(tmp_path / "s2" / "arva.raw").reads] == [b"y"]


WRITER = r"""
import sys, time
from bench.session import SessionWriter
w = SessionWriter(sys.argv[1], {"devices": {"arva": {"kind": "arva"}}})
i = 0
while True:
    w.raw("arva", b"%08d" % i)
    if i % 100 == 0:
        print(i, flush=True)
    i += 1
    time.sleep(0.0005)
"""


@pytest.mark.subprocess
def test_sigkill_loses_nothing_before_the_last_second(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path / "s")], stdout=subprocess.PIPE, text=True)
    reported = []
    t_end = time.monotonic() + 1.5
    while time.monotonic() < t_end:
        reported.append((time.monotonic(), int(proc.stdout.readline())))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    # What the writer had written 1 s before the kill must all be there, in order.
    kill_time = time.monotonic()
    must_have = max(n for t, n in reported if t < kill_time - 1.0)
    got = read_raw(tmp_path / "s" / "arva.raw")
    values = [int(r.data) for r in got.reads]
    assert values == list(range(len(values)))
    assert len(values) > must_have
    assert read_manifest(tmp_path / "s")["format"] == "arva-session"
    assert json.loads((tmp_path / "s" / "events.jsonl").read_text().splitlines()[0])["event"] == "start"


def test_not_a_session(tmp_path):
    with pytest.raises(InputError, match=r"not a session directory \(no manifest.json\)$"):
        read_manifest(tmp_path)


def test_a_full_disk_while_a_logger_stops_is_reported_not_raised(tmp_path):
    from bench.ingest.reader import Device, Notifier
    from bench.logger import DeviceSpec, SessionListener
    from firmware_proto.sentences import encode_parva

    class FullWriter:
        def event(self, kind, **fields):
            pass

        def raw(self, *a):
            pass

        def record(self, device, record):
            raise LinkError(f"{tmp_path}/arva.jsonl: write failed: No space left on device")

    fatal = []
    dev = Device(DeviceSpec("arva", "arva", str(tmp_path / "no-such-tty")))
    notifier = Notifier([dev], [SessionListener(FullWriter())], on_error=fatal.append)
    notifier.start()
    # One slot of a two-slot epoch: flushed at stop as an incomplete epoch record.
    assert dev.decoder.feed(encode_parva(7, 2, 1, 1, 100, 0)) == []
    notifier.stop()  # must not raise: the session still gets closed by its owner
    assert [str(e) for e in fatal] == [f"{tmp_path}/arva.jsonl: write failed: No space left on device"]


def test_a_full_disk_still_leaves_a_finished_manifest(tmp_path, monkeypatch):
    """The new manifest cannot be created: it is written over the old one's padding, and
    no manifest.json.tmp stays behind."""
    import builtins

    w = SessionWriter(tmp_path / "s", {"devices": {"arva": {"kind": "arva", "url": "x"}}})
    w.raw("arva", b"$PARVA,0,1,1,-1,-1,-1*78\r\n", mono=1.0, utc=1.8e9)
    real_open = builtins.open

    def full(path, mode="r", *a, **k):
        if str(path).endswith(".tmp") and "w" in mode:
            f = real_open(path, mode, *a, **k)
            f.close()
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_open(path, mode, *a, **k)

    monkeypatch.setattr(builtins, "open", full)
    w.close(devices={"arva": {"reads": 1}}, stopped_by="disk error")
    monkeypatch.undo()
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["arva.raw", "events.jsonl", "manifest.json"]
    m = read_manifest(tmp_path / "s")
    assert m["stop_utc"] >= m["start_utc"]
    assert m["summary"] == {"devices": {"arva": {"reads": 1}}, "stopped_by": "disk error"}


def test_a_jsonl_line_nested_too_deep_is_one_error_not_a_recursion_error(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_bytes(b'{"event": "start"}\n' + b"[" * 100000 + b"]" * 100000 + b"\n")
    with pytest.raises(InputError, match=r"events.jsonl: line 2: JSON nested more than 32 deep$"):
        list(read_jsonl(path))


def test_a_jsonl_line_longer_than_the_cap_is_refused_without_reading_it_whole(tmp_path):
    from bench.session import MAX_JSONL_LINE

    path = tmp_path / "a.jsonl"
    path.write_bytes(b'{"n": 1}\n"' + b"x" * MAX_JSONL_LINE + b'"\n')
    with pytest.raises(InputError, match=rf"a.jsonl: line 2: longer than {MAX_JSONL_LINE} bytes \(not a JSON lines line\)$"):
        list(read_jsonl(path))


def test_a_jsonl_line_json_refuses_for_its_size_is_one_error_line(tmp_path):
    """Python's json refuses integers of more than 4300 digits with a plain ValueError
    (not a JSONDecodeError): still "not JSON", not a traceback; as a torn tail, skipped."""
    path = tmp_path / "events.jsonl"
    path.write_bytes(b'{"n": 1}\n{"n": ' + b"9" * 5000 + b"}\n")
    with pytest.raises(InputError, match=r"events.jsonl: line 2: not JSON$"):
        list(read_jsonl(path))
    path.write_bytes(b'{"n": 1}\n{"n": ' + b"9" * 5000)  # torn: no newline
    assert list(read_jsonl(path)) == [{"n": 1}]
