"""``arva-bench cat``: files, stdin, FIFOs, pyserial URLs; exit codes and messages."""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import termios
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
import repo_paths

import bench.cat as cat
from bench.cli import main
from firmware_proto.sentences import encode_epoch

EMPTY = (-1, -1, -1)
CAT = [sys.executable, "-m", "bench.cli", "cat"]
ROOT = repo_paths.ROOT
ZERO_ERRORS = " ".join(
    f"errors.{k}=0"
    for k in ("BAD_CHECKSUM", "TOO_LONG", "NON_ASCII", "MALFORMED", "OUT_OF_RANGE", "UNKNOWN_SENTENCE", "TRUNCATED")
)

STREAM = (
    encode_epoch(0, [(1, 1905, 21), EMPTY])
    + b"\x00\xffjunk"
    + encode_epoch(1, [(2, 300, -4), (1, 1890, 20)])[:-10]  # slot 2 cut short
    + encode_epoch(3, [(2, 290, -4), (1, 1880, 19)])
)
STREAM_JSON = [
    {"seq": 0, "complete": True, "slots": [[1, 1905, 21], [-1, -1, -1]]},
    {"seq": 1, "complete": False, "slots": [[2, 300, -4], None]},
    {"seq": 3, "complete": True, "slots": [[2, 290, -4], [1, 1880, 19]]},
]
STREAM_STATS = (
    f"arva-bench: cat: bytes={len(STREAM)} garbage_bytes=6 sentences_ok=5 epochs_complete=2 epochs_incomplete=1 "
    "seq_gaps=1 seqs_missing=1 seq_wraps=0 fields_orphaned=0 "
    + ZERO_ERRORS.replace("TRUNCATED=0", "TRUNCATED=1")
)


def run_cat(args: list[str], stdin: bytes | None = None, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run(
        CAT + args, input=stdin, capture_output=True, timeout=timeout, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}
    )


def json_lines(out: bytes) -> list[dict]:
    return [json.loads(line) for line in out.decode().splitlines()]


def assert_whole_stream(returncode: int, out: bytes, err: bytes) -> None:
    """cat read STREAM to its end: exit 0, its JSON lines, its statistics line."""
    assert returncode == 0
    assert json_lines(out) == STREAM_JSON
    assert err.decode() == STREAM_STATS + "\n"


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_file_source(tmp_path: Path) -> None:
    path = tmp_path / "rx.nmea"
    path.write_bytes(STREAM)
    proc = run_cat([str(path)])
    assert_whole_stream(proc.returncode, proc.stdout, proc.stderr)


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_stdin_source_and_exact_json_text() -> None:
    data = encode_epoch(9, [(1, 1905, 21)], [(1.25e-05, -2.5e-06, 0.0)])
    proc = run_cat(["-", "--expect-fields"], stdin=data)
    assert proc.returncode == 0
    assert proc.stdout == (
        b'{"seq": 9, "complete": true, "slots": [[1, 1905, 21]], "field": [[1.25e-05, -2.5e-06, 0.0]]}\n'
    )


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_garbage_only_stream_exits_zero_with_everything_counted() -> None:
    data = b"\xff" * 100 + b"$PARVA,1,1*00\r\n" + b"$" + b"A" * 90 + b"\r\n" + b"$PARVA,9"
    proc = run_cat(["-"], stdin=data)
    assert proc.returncode == 0 and proc.stdout == b""
    assert proc.stderr.decode() == (
        f"arva-bench: cat: bytes={len(data)} garbage_bytes=111 sentences_ok=0 epochs_complete=0 epochs_incomplete=0 "
        "seq_gaps=0 seqs_missing=0 seq_wraps=0 fields_orphaned=0 "
        + ZERO_ERRORS.replace("BAD_CHECKSUM=0", "BAD_CHECKSUM=1")
        .replace("TOO_LONG=0", "TOO_LONG=1")
        .replace("TRUNCATED=0", "TRUNCATED=1")
        + "\n"
    )


@pytest.mark.subprocess
@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["/nonexistent/rx.nmea"], "arva-bench: cat: /nonexistent/rx.nmea: No such file or directory"),
        (["bogus://x"], "arva-bench: cat: bogus://x: invalid URL, protocol 'bogus' not known"),
        ([str(ROOT)], f"arva-bench: cat: {ROOT}: Is a directory"),
        ([], "arva-bench: cat: the following arguments are required: SOURCE (see arva-bench cat --help)"),
        (["-", "--epochs", "0"], "arva-bench: cat: argument --epochs: must be >= 1, got 0 (see arva-bench cat --help)"),
        (["-", "--until-idle", "-1"],
         "arva-bench: cat: argument --until-idle: must be > 0, got -1 (see arva-bench cat --help)"),
    ],  # fmt: skip
)
def test_bad_arguments_exit_2_with_one_line(args: list[str], message: str) -> None:
    proc = run_cat(args, stdin=b"")
    assert proc.returncode == 2
    assert proc.stdout == b""
    assert proc.stderr.decode() == message + "\n"


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_unreachable_socket_url_exits_2() -> None:
    proc = run_cat(["socket://127.0.0.1:1"])
    assert proc.returncode == 2
    lines = proc.stderr.decode().splitlines()
    assert len(lines) == 1 and lines[0].startswith("arva-bench: cat: socket://127.0.0.1:1: ")
    assert "Traceback" not in proc.stderr.decode()


@pytest.mark.timeout(60)
def test_loop_url_in_process(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    opened = []

    def loop_with_data(url: str, baudrate: int, timeout: float) -> serial.SerialBase:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout)
        port.write(STREAM)
        opened.append(port)
        return port

    monkeypatch.setattr(cat, "open_device", loop_with_data)
    assert main(["cat", "loop://", "--until-idle", "0.3"]) == 0
    out, err = capsys.readouterr()
    assert json_lines(out.encode()) == STREAM_JSON
    assert err == STREAM_STATS + "\n"
    assert opened and not opened[0].is_open  # closed at the end


@pytest.mark.timeout(60)
def test_epochs_option_stops_early(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def loop_with_data(url: str, baudrate: int, timeout: float) -> serial.SerialBase:
        port = serial.serial_for_url(url, timeout=timeout)
        port.write(b"".join(encode_epoch(s, [(1, 100 + s, 0)]) for s in range(50)))
        return port

    monkeypatch.setattr(cat, "open_device", loop_with_data)
    assert main(["cat", "loop://", "--epochs", "3"]) == 0
    out, _ = capsys.readouterr()
    assert [o["seq"] for o in json_lines(out.encode())] == [0, 1, 2]


def _read_line(stream, timeout: float) -> bytes:  # type: ignore[no-untyped-def]
    """One line from a pipe, failing after ``timeout`` seconds instead of hanging."""
    buf = b""
    deadline = time.monotonic() + timeout
    fd = stream.fileno()
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(0.0, left))
        if not ready:
            raise AssertionError(f"no line within {timeout} s (got {buf!r})")
        chunk = os.read(fd, 1)
        if not chunk:
            raise AssertionError(f"EOF before a full line (got {buf!r})")
        buf += chunk
    return buf


def _default_sigint() -> None:
    """In the child: Ctrl-C as at a terminal. A suite started in the background by a
    non-interactive shell (``make test &``) ignores SIGINT, and an ignored signal
    stays ignored across exec: the command would then never see the test's SIGINT."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@contextlib.contextmanager
def running(args: list[str]) -> Iterator[subprocess.Popen]:
    """cat with ``args``, its three pipes open; killed on the way out if still running."""
    proc = subprocess.Popen(
        CAT + args,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        preexec_fn=_default_sigint,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)


@pytest.mark.subprocess
@pytest.mark.timeout(60)
@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["ctrl_c", "sigterm"])
def test_live_stream_epochs_appear_without_waiting_and_a_stop_signal_prints_stats(sig: int, status: int) -> None:
    with running(["-"]) as proc:
        assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
        proc.stdin.write(encode_epoch(5, [(1, 1905, 21)]))
        proc.stdin.flush()
        assert json.loads(_read_line(proc.stdout, 10)) == {"seq": 5, "complete": True, "slots": [[1, 1905, 21]]}
        # A research epoch whose last slot is empty has no $PARVH: it is held, and released
        # by the idle timeout while the input is still open.
        proc.stdin.write(encode_epoch(6, [(1, 1904, 21), EMPTY], [(1.0, 2.0, 3.0), None]))
        proc.stdin.flush()
        assert json.loads(_read_line(proc.stdout, 10)) == {
            "seq": 6, "complete": True, "slots": [[1, 1904, 21], [-1, -1, -1]], "field": [[1.0, 2.0, 3.0], None],
        }  # fmt: skip
        proc.stdin.write(encode_epoch(7, [(1, 1903, 21), (2, 400, 3)])[:30])  # first slot only
        proc.stdin.flush()
        time.sleep(0.3)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == status
    assert json.loads(out) == {"seq": 7, "complete": False, "slots": [[1, 1903, 21], None]}
    assert err.decode().startswith("arva-bench: cat: bytes=")
    assert "epochs_complete=2 epochs_incomplete=1" in err.decode() and "Traceback" not in err.decode()


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_fifo_source(tmp_path: Path) -> None:
    fifo = tmp_path / "rx.fifo"
    os.mkfifo(fifo)
    with running([str(fifo)]) as proc:
        with open(fifo, "wb") as w:  # blocks until cat opened the read side
            w.write(STREAM)
        out, err = proc.communicate(timeout=20)
    assert_whole_stream(proc.returncode, out, err)


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_closed_stdout_is_not_an_error(tmp_path: Path) -> None:
    path = tmp_path / "big.nmea"
    path.write_bytes(b"".join(encode_epoch(s % 65536, [(1, s % 1000, 0)]) for s in range(20000)))
    with running([str(path)]) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        assert json.loads(_read_line(proc.stdout, 10))["seq"] == 0
        proc.stdout.close()
        proc.wait(timeout=20)
        err = proc.stderr.read().decode()
    assert proc.returncode == 0
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert err.startswith("arva-bench: cat: bytes=")


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_emulator_url_end_to_end() -> None:
    """cat reads the emulator's in-process receiver URL (arvaemu://) like any port."""
    proc = run_cat(["arvaemu://?speed=0&frames=3", "--epochs", "3"])
    assert proc.returncode == 0, proc.stderr
    out = json_lines(proc.stdout)
    assert [o["seq"] for o in out] == [0, 1, 2] and all(o["complete"] for o in out)


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.pty
@pytest.mark.timeout(60)
def test_character_device_source_via_pty() -> None:
    """A device path (here a pty slave) is opened with pyserial, like /dev/ttyUSB0."""
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        proc = subprocess.Popen(
            CAT + [path, "--epochs", "2"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )
        try:
            # pyserial flushes the input when it opens the port: write only once cat has
            # put the line in raw mode (and a moment more for that flush).
            deadline = time.monotonic() + 20
            while termios.tcgetattr(slave)[3] & termios.ICANON:
                assert time.monotonic() < deadline and proc.poll() is None, "cat did not open the pty"
                time.sleep(0.02)
            time.sleep(0.2)
            os.write(master, encode_epoch(40, [(1, 1905, 21)]) + encode_epoch(41, [(1, 1904, 21)]))
            out, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    finally:
        os.close(master)
        os.close(slave)
    assert proc.returncode == 0, err
    assert json_lines(out) == [
        {"seq": 40, "complete": True, "slots": [[1, 1905, 21]]},
        {"seq": 41, "complete": True, "slots": [[1, 1904, 21]]},
    ]
