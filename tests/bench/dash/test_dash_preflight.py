"""``arva-bench dash`` and ``log`` refuse sources that can never work before they start (issue 16):
exit 2, one line. A device path that does not exist (yet) is still retried by the TUI."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bench.preflight import check_source
from firmware_proto.errors import InputError


def dash(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.cli", "dash", *argv], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=60)  # fmt: skip


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("preflight")
    garbage = root / "garbage.bin"
    garbage.write_bytes(bytes(range(256)) * 8)
    bad_scene = root / "bad.toml"
    bad_scene.write_text("spec = 1\n[model]\nr_en = 1e300\n[receiver]\nposition = [0, 0, 0]\n")
    good = root / "good.nmea"
    good.write_bytes(b"noise\r\n$PARVA,0,1,1,1,761,-62*4C\r\n")
    return root, garbage, bad_scene, good


@pytest.mark.slow
@pytest.mark.subprocess
def test_sources_that_can_never_work_exit_2_before_the_tui(files):
    root, garbage, bad_scene, _ = files
    cases = [
        (["bogus://x"], "arva-bench: dash: bogus://x: unknown URL scheme 'bogus'\n"),
        ([f"arvaemu://{root}/missing.toml"], f"arva-bench: dash: {root}/missing.toml: cannot read: No such file or directory\n"),
        ([f"arvaemu://{bad_scene}"], f"arva-bench: dash: {bad_scene}: model.r_en: must be <= 1000000000, got 1e+300\n"),
        ([str(garbage)], f"arva-bench: dash: {garbage}: no valid $PARVA sentence in the first 2048 bytes\n"),
        # issue 29, item 4: a scene that would never end
        (["arvaemu:///dev/zero"], "arva-bench: dash: /dev/zero: a character device, not a regular file: only regular "
                                  "files are read as a scene file\n"),
    ]
    for argv, message in cases:
        p = dash(*argv)
        assert (p.returncode, p.stdout, p.stderr) == (2, "", message), argv


def test_sources_that_may_work_later_pass(files):
    root, _, _, good = files
    check_source(str(root / "ttyUSB-not-plugged-yet"))  # retried by the TUI
    check_source(str(good))
    check_source("arvaemu://")
    check_source("socket://127.0.0.1:1")  # a server may come up later
    with pytest.raises(InputError):
        check_source("arvaemu://?speed=nan")


@pytest.mark.subprocess
def test_log_refuses_them_too_and_creates_no_session(files, tmp_path):
    _, garbage, bad_scene, _ = files
    p = subprocess.run([sys.executable, "-m", "bench.cli", "log", "--arva", "bogus://x", "--out", str(tmp_path / "s"),
                        "--duration", "1"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert (p.returncode, p.stderr) == (2, "arva-bench: log: bogus://x: unknown URL scheme 'bogus'\n")
    assert not (tmp_path / "s").exists()


@pytest.mark.slow
@pytest.mark.subprocess
def test_a_missing_path_or_an_unusable_record_dir_is_refused_before_the_screen(tmp_path):
    """Issue 29, item 10: the dashboard started its screen for these and showed a dead panel
    (or failed when r was pressed); now one line, exit 2, before the TUI."""
    missing = tmp_path / "no-such-session"
    cases = [
        ([str(missing)], f"arva-bench: dash: {missing}: no such file, device or session directory (a device not "
                         "plugged in yet is waited for only under /dev/)\n"),
        (["arvaemu://", "--gps", str(missing)], f"arva-bench: dash: {missing}: no such file, device or session "
                                                "directory (a device not plugged in yet is waited for only under /dev/)\n"),
        (["--record-dir", "/proc/x"], "arva-bench: dash: --record-dir /proc/x: cannot create it in /proc: "
                                      "No such file or directory\n"),
    ]  # fmt: skip
    for argv, message in cases:
        p = dash(*argv)
        assert (p.returncode, p.stdout, p.stderr) == (2, "", message), argv
    assert list(tmp_path.iterdir()) == []  # the probe leaves nothing


def test_a_device_not_plugged_in_yet_is_waited_for_under_dev():
    from bench.dash.cli import check_path_may_appear

    check_path_may_appear("/dev/ttyUSB-not-plugged-yet")
    check_path_may_appear("/dev/serial/by-id/usb-not-yet")
    with pytest.raises(InputError, match=r"^dash: nope: no such file"):
        check_path_may_appear("nope")
