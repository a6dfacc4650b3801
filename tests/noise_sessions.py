"""Sessions full of line noise, and the peak memory of a command reading one (issue 29).

Shared by tests/bench/ingest/test_line_noise.py (small sizes) and tests/perf/noise_cost.py (the 60 MB
figures of docs/reliability.md). A noise session is what ``arva-bench log`` writes for a
receiver whose line carries ``noise`` bytes of ``$`` in 64 KiB reads at 115200 Bd, with a
valid epoch after every read, a GPS and an attitude unit on the receiver and a surveyed
transmitter: it exports one row per epoch.
"""

from __future__ import annotations

import datetime as _dt
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.session import SessionWriter
from emulator.frames.geodesy import Origin, enu_to_geodetic
from emulator.truth.nmea import gps_sentences
from firmware_proto.sentences import encode_parva

PASHR = b"$PASHR,080000.000,123.40,T,+01.50,-02.00,+00.00,0.050,0.050,0.100,1,1*06\r\n"
CHUNK = 65536
BAUD = 115200
START_UTC = 1768471200.0  # 2026-01-15T10:00:00Z
ORIGIN = Origin(46.5, 8.0, 2500.0)


def noise_session(directory: Path, noise: int, byte: bytes = b"$") -> int:
    """Write a session with ``noise`` bytes of ``byte`` on the receiver's line (and an
    epoch after each 64 KiB of it), a receiver GPS fix and attitude every second; returns the noise bytes written."""
    w = SessionWriter(directory, {"devices": {"arva": {"kind": "arva", "url": "x", "role": "rx", "baudrate": BAUD},
                                              "gps-rx": {"kind": "gps", "url": "y", "role": "rx"},
                                              "attitude-rx": {"kind": "attitude", "url": "z", "role": "rx"}},
                                  "origin": {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt},
                                  "tx_poses": {"1": {"lat": 46.5001, "lon": 8.0, "alt": 2500.0}}})  # fmt: skip
    lat, lon, alt = (float(v) for v in enu_to_geodetic(0.0, 0.0, 1.0, ORIGIN))
    t = fixed = 0.0
    sent = k = 0
    while sent < noise or k < 2:
        junk = byte * min(CHUNK, noise - sent)
        data = junk + b"\r\n" + encode_parva(k % 65536, 1, 1, 1, 1100, 3)
        t += len(data) * 10 / BAUD  # the line time of the read
        while fixed <= t + 1.0:
            utc = _dt.datetime.fromtimestamp(START_UTC + fixed, _dt.timezone.utc)
            w.raw("gps-rx", gps_sentences(utc, lat, lon, alt), mono=100.0 + fixed, utc=START_UTC + fixed)
            w.raw("attitude-rx", PASHR, mono=100.0 + fixed, utc=START_UTC + fixed)
            fixed += 1.0
        w.raw("arva", data, mono=100.0 + t, utc=START_UTC + t)
        sent += len(junk)
        k += 1
    w.close()
    return sent


def log_noise(directory: Path, noise: int, byte: bytes = b"$") -> dict:
    """What ``arva-bench log`` writes for a receiver line carrying ``noise`` bytes of
    ``byte`` in 64 KiB reads at 115200 Bd (its listener, fed in this process); the device's
    summary."""
    from bench.ingest.reader import Device, DeviceSpec
    from bench.logger import SessionListener

    spec = DeviceSpec("arva", "arva", "x", baudrate=BAUD)
    writer = SessionWriter(directory, {"devices": {"arva": spec.manifest()}})
    device, listener = Device(spec), SessionListener(writer)
    t, sent = 100.0, 0
    while sent < noise:
        data = byte * min(CHUNK, noise - sent)
        t += len(data) * 10 / BAUD
        listener.on_read(device, device.ingest(data, t, START_UTC + t))
        sent += len(data)
    listener.on_read(device, device.stop(t + 1.0, START_UTC + t + 1.0))
    summary = listener.summary([device])
    writer.close(devices=summary)
    return summary["arva"]


def peak_rss(argv: list[str], timeout: float = 600.0, how: tuple[str, ...] = ("-m", "bench.cli"),
             env: dict | None = None, cwd: Path | None = None) -> tuple[int, str, int, float]:  # fmt: skip
    """Run ``python HOW ARGV`` (default ``-m bench.cli``) in ``cwd``: (exit status, stderr,
    peak RSS in kB, seconds). With ``-m`` or ``-c`` the working directory comes first on
    ``sys.path``: run it elsewhere than a source tree to measure the code on PYTHONPATH."""
    t0 = time.monotonic()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, *how, *argv], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=err, env=env, cwd=cwd)  # fmt: skip
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - t0 > timeout:
                proc.kill()
                os.wait4(proc.pid, 0)
                raise TimeoutError(f"{argv}: still running after {timeout:g} s")
            time.sleep(0.02)
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        err.seek(0)
        text = err.read().decode(errors="replace")
    return proc.returncode, text, usage.ru_maxrss, time.monotonic() - t0
