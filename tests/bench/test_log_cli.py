"""arva-bench log: argument errors are one line and exit 2; loop:// devices log."""

import subprocess
import sys

import pytest

from bench.session import read_jsonl, read_manifest

pytestmark = pytest.mark.subprocess


def bench(*args, timeout=30):
    return subprocess.run([sys.executable, "-m", "bench.cli", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--gps", "loop://"], "arva-bench: log: no receiver: give at least one --arva URL\n"),
        (["--arva", "loop://", "--gps", "loop://", "--gps", "loop://"],
         "arva-bench: log: two devices would both be 'gps-rx': give them different roles\n"),
    ],
)
def test_log_argument_errors(tmp_path, args, message):
    proc = bench("log", *args, "--out", str(tmp_path / "s"))
    assert proc.returncode == 2 and proc.stderr == message and proc.stdout == ""
    assert not (tmp_path / "s").exists()  # nothing created for a command that cannot run


def test_bad_role_is_an_argparse_error(tmp_path):
    proc = bench("log", "--arva", "loop://", "--gps", "loop://,role=boat", "--out", str(tmp_path / "s"))
    assert proc.returncode == 2
    assert "role must be rx, rx<ID> or tx<ID>, got 'boat'" in proc.stderr


def test_existing_session_is_never_overwritten(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "keep").write_text("x")
    proc = bench("log", "--arva", "loop://", "--out", str(tmp_path / "s"))
    assert proc.returncode == 2
    assert proc.stderr == f"arva-bench: {tmp_path / 's'}: not empty; a session never overwrites another (choose a new --out)\n"


@pytest.mark.slow
def test_unavailable_device_is_recorded_and_the_rest_logs(tmp_path):
    proc = bench("log", "--arva", "arvaemu://?speed=20", "--gps", "/dev/ttyNOPE7", "--out", str(tmp_path / "s"),
                 "--duration", "1.5")
    assert proc.returncode == 0, proc.stderr
    events = list(read_jsonl(tmp_path / "s" / "events.jsonl"))
    assert [(e["event"], e.get("device")) for e in events[:2]][1] == ("unavailable", "gps-rx")
    seqs = [r["seq"] for r in read_jsonl(tmp_path / "s" / "arva.jsonl") if "seq" in r]
    assert seqs[:5] == [0, 1, 2, 3, 4] and len(seqs) >= 20
    assert read_manifest(tmp_path / "s")["devices"]["gps-rx"]["url"] == "/dev/ttyNOPE7"


def test_a_duration_stop_says_so_and_flags_no_cut_sentence(tmp_path):
    proc = bench("log", "--arva", "arvaemu://?speed=50", "--out", str(tmp_path / "s"), "--duration", "1.0")
    assert proc.returncode == 0, proc.stderr
    manifest = read_manifest(tmp_path / "s")
    assert manifest["summary"]["stopped_by"] == "duration" and "stop_utc" in manifest
    records = list(read_jsonl(tmp_path / "s" / "arva.jsonl"))
    assert len(records) >= 20 and [r for r in records if "error" in r] == []
    assert manifest["summary"]["devices"]["arva"]["decoder"]["errors"] == 0


def test_no_device_delivering_a_byte_is_exit_2_and_names_the_devices_never_opened(tmp_path):
    import serial

    try:
        serial.Serial("/dev/ttyNOPE8")
    except serial.SerialException as exc:
        reason = str(exc)
    proc = bench("log", "--arva", "/dev/ttyNOPE8", "--out", str(tmp_path / "s"), "--duration", "0.3")
    # Exit 2 is one line (issue 29): the device never opened and why, folded in.
    assert (proc.returncode, proc.stderr) == (2, f"arva-bench: log: no device delivered a byte (arva never opened: "
                                                 f"{reason}); {tmp_path / 's'} holds only the manifest and events\n")
    assert read_manifest(tmp_path / "s")["summary"]["devices"]["arva"]["never_opened"] == reason


def _file_size_limit(limit: int):
    """For the child: files larger than ``limit`` bytes cannot be written (EFBIG, as a full
    disk gives ENOSPC), and SIGXFSZ is ignored (the write fails instead of the process)."""

    def preexec() -> None:
        import resource
        import signal

        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    return preexec


def test_a_full_disk_is_one_line_and_the_session_stays_readable(tmp_path):
    out = tmp_path / "s"
    proc = subprocess.run([sys.executable, "-m", "bench.cli", "log", "--arva", "arvaemu://?speed=0&frames=100000",
                           "--out", str(out), "--duration", "30"], capture_output=True, text=True, timeout=120,
                          preexec_fn=_file_size_limit(100_000))  # fmt: skip
    assert (proc.returncode, proc.stderr) == (2, f"arva-bench: log: {out / 'arva.raw'}: write failed: File too large; "
                                                 "the session was closed, everything before is kept\n")
    manifest = read_manifest(out)
    assert manifest["summary"]["stopped_by"] == "disk error"
    assert [e["event"] for e in read_jsonl(out / "events.jsonl")] == ["start", "stop"]


def test_a_note_that_is_not_utf8_is_refused(tmp_path):
    proc = subprocess.run([sys.executable.encode(), b"-m", b"bench.cli", b"log", b"--arva", b"arvaemu://", b"--out",
                           bytes(tmp_path / "s"), b"--note", b"caf\xe9 au lait"], capture_output=True, timeout=60)  # fmt: skip
    assert (proc.returncode, proc.stderr) == (2, b"arva-bench log: error: argument --note: not UTF-8 text (byte 3)\n")
    assert not (tmp_path / "s").exists()
