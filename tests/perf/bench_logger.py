"""Bench logging (issue 5). Prints tables and writes docs/performance.md.

1. Ingest: three receivers streaming as fast as possible on three ptys into one
   `arva-bench log`; sentences/s summed, and whether every epoch arrived (zero loss).
2. Disk: bytes per hour of a typical 3-device session (receiver 1 Hz with 4 channels,
   GPS 1 Hz RMC+GGA, attitude 10 Hz $PASHR), logged at 120x real time for 30 s.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from _report import ROOT, markdown_table, write_section  # noqa: E402
from emulator.testing import EmulatorProcess  # noqa: E402

from bench.session import read_jsonl, read_raw  # noqa: E402

PAPER_TX = (ROOT / "emulator" / "scenes" / "default.toml").read_text().split("[receiver]")[0]
CHANNELS = 20  # sentences per epoch: empty slots are sentences too


def three_rx(rate_hz: float) -> str:
    head = PAPER_TX.replace("rate_hz = 1.0", f"rate_hz = {rate_hz}")
    return head + "".join(
        f"[[receivers]]\nid = {i}\nchannels = {CHANNELS}\nposition = [{x}, 0.0, 0.0]\n"
        for i, x in ((1, 0.0), (2, 5.0), (3, 10.0))
    )


TYPICAL = PAPER_TX.replace("[[transmitters]]", "[origin]\nlat = 46.5\nlon = 8.0\nalt = 2500.0\n"
                           "[ground_truth]\ngps_rate_hz = 1.0\nattitude_rate_hz = 10.0\n\n[[transmitters]]", 1) + (
    "[receiver]\nchannels = 4\ngps = true\nattitude = true\n"
    "path = [ { t = 0.0, position = [-40.0, -40.0, 1.0] }, { t = 3600.0, position = [40.0, 40.0, 1.0] } ]\n"
)


def log_cmd(ports: dict[str, str], out: Path, duration: float) -> list[str]:
    cmd = [sys.executable, "-m", "bench.cli", "log", "--out", str(out), "--duration", str(duration)]
    for label, path in ports.items():
        if label.startswith("arva"):
            cmd += ["--arva", f"{path},role=rx{label.split(':')[1]}" if ":" in label else path]
        else:
            cmd += [f"--{label.split(':')[0]}", path]
    return cmd


def ingest(tmp: Path, target: float, seconds: float) -> dict:
    """Three receivers at a fixed real-time rate summing to ``target`` sentences/s."""
    rate = target / (3 * CHANNELS)
    frames = int(rate * seconds)
    scene = tmp / "three.toml"
    scene.write_text(three_rx(rate))
    emu = EmulatorProcess("--scene", str(scene), "--port", "pty", "--speed", "1", "--frames", str(frames),
                          "--delay", "2", streams=3)
    out = tmp / f"ingest-{int(target)}"
    try:
        logger = subprocess.Popen(log_cmd(emu.ports, out, 600), stderr=subprocess.PIPE, text=True)
        emu.wait(timeout=600)
        emu_err = emu.stderr().strip()
        time.sleep(1.0)
        logger.terminate()
        logger.wait(timeout=60)
    finally:
        emu.kill()
    sentences, first, last, complete = 0, float("inf"), 0.0, True
    for name in ("arva-rx1", "arva-rx2", "arva-rx3"):
        raw = read_raw(out / f"{name}.raw").reads
        sentences += b"".join(r.data for r in raw).count(b"$PARVA")  # sentences span reads
        first, last = min(first, raw[0].mono), max(last, raw[-1].mono)
        seqs = [r["seq"] for r in read_jsonl(out / f"{name}.jsonl") if "seq" in r]
        complete &= seqs == [k % 65536 for k in range(frames)]
    dropped = int(emu_err.split("), ")[1].split()[0])
    return {"target": target, "sentences": sentences, "seconds": last - first, "rate": sentences / (last - first),
            "complete": complete and dropped == 0, "dropped": dropped}


def disk_per_hour(tmp: Path, speed: float, seconds: float) -> dict:
    scene = tmp / "typical.toml"
    scene.write_text(TYPICAL)
    frames = int(speed * seconds)
    emu = EmulatorProcess("--scene", str(scene), "--port", "pty", "--speed", str(speed), "--frames", str(frames),
                          "--delay", "2", streams=3)
    out = tmp / "typical"
    try:
        logger = subprocess.Popen(log_cmd(emu.ports, out, seconds + 3.0), stderr=subprocess.PIPE, text=True)
        emu.proc.wait(timeout=seconds + 60)
        logger.wait(timeout=seconds + 60)
    finally:
        emu.kill()
    sizes = {p.name: p.stat().st_size for p in sorted(out.iterdir())}
    total = sum(sizes.values())
    scene_hours = frames / 3600.0
    return {"per_hour": total / scene_hours, "sizes": {k: v / scene_hours for k, v in sizes.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="50000,100000,150000", help="offered sentences/s (summed) to try")
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each ingest run")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        runs = [ingest(tmp, float(t), args.seconds) for t in args.targets.split(",")]
        disk = disk_per_hour(tmp, 120.0, 30.0)
    t1 = markdown_table(
        ["offered (sentences/s)", "logged sentences", "seconds", "logged sentences/s (3 ptys summed)",
         "zero loss (every epoch logged, in order; 0 bytes dropped)"],
        [[f"{r['target']:,.0f}", f"{r['sentences']:,}", f"{r['seconds']:.2f}", f"{r['rate']:,.0f}",
          "yes" if r["complete"] else f"NO ({r['dropped']:,} bytes dropped)"] for r in runs],
    )
    t2 = markdown_table(
        ["file", "MB per hour"],
        [[k, f"{v / 1e6:.2f}"] for k, v in disk["sizes"].items()] + [["**total**", f"**{disk['per_hour'] / 1e6:.2f}**"]],
    )
    body = ("Ingest (target >= 50,000 sentences/s summed, zero loss): three emulated receivers, 20 "
            f"channels each, in real time on three ptys into one `arva-bench log`, {args.seconds:.0f} s of "
            "epochs per offered rate. Emulator and logger share the machine's 2 cores; where the logged "
            "rate is below the offered one and 'seconds' exceeds the run length, the emulator could not "
            "offer more (it fell behind its deadlines), not the logger losing data.\n\n" + t1 +
            "\n\nDisk per hour of a typical session (receiver 1 Hz x 4 channels, GPS 1 Hz, attitude 10 Hz; "
            "raw reads base64 with timestamps plus decoded JSON lines), measured over 1 hour of scene time "
            "at 120x:\n\n" + t2)
    print(body)
    if not args.no_write:
        write_section("logger", "Bench logging", body, "python tests/perf/bench_logger.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
