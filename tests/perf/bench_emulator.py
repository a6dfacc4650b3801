"""Emulator on a pty (issue 4). Prints tables and writes docs/performance.md.

1. Real-time precision: 20 Hz epochs for 30 s; a pyserial reader timestamps the first
   sentence of every epoch; p50/p99/max of |arrival interval - 50 ms|.
2. As fast as possible with a reader keeping up: epochs/s, and every epoch received.
3. What each effect costs: time per epoch of the ideal scene and with one effect on.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import serial

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from _report import ROOT, markdown_table, write_section  # noqa: E402
from emulator_proc import EmulatorProcess  # noqa: E402

DEFAULT = (ROOT / "emulator" / "scenes" / "default.toml").read_text()


def scene_file(tmp: Path, text: str, name: str = "scene.toml") -> str:
    path = tmp / name
    path.write_text(text)
    return str(path)


def jitter(tmp: Path, rate_hz: float, seconds: float) -> dict:
    scene = scene_file(tmp, DEFAULT.replace("rate_hz = 1.0", f"rate_hz = {rate_hz}"))
    frames = int(rate_hz * seconds)
    emu = EmulatorProcess("--scene", scene, "--port", "pty", "--frames", str(frames), "--delay", "1")
    arrivals = []
    try:
        with serial.Serial(emu.ports["arva"], timeout=2) as ser:
            # Read whatever has arrived, timestamp it at once; an epoch's arrival is
            # the chunk that carries its first sentence (slot 1 of 4).
            while len(arrivals) < frames:
                try:
                    chunk = ser.read(max(ser.in_waiting, 1))
                except (OSError, serial.SerialException):
                    break  # the emulator finished and closed the pty
                if not chunk:
                    break
                now = time.monotonic()
                arrivals.extend([now] * chunk.count(b",4,1,"))
        emu.stop()
    finally:
        emu.kill()
    dev_ms = np.abs(np.diff(arrivals) - 1.0 / rate_hz) * 1000.0
    return {
        "epochs": len(arrivals),
        "p50": float(np.percentile(dev_ms, 50)),
        "p99": float(np.percentile(dev_ms, 99)),
        "max": float(dev_ms.max()),
    }


def fast_with_reader(tmp: Path, frames: int) -> dict:
    emu = EmulatorProcess("--port", "pty", "--frames", str(frames), "--speed", "0", "--delay", "1")
    received = bytearray()
    try:
        ser = serial.Serial(emu.ports["arva"], timeout=0.5)

        def reader():
            # Read whatever is there in large chunks until the emulator has exited and
            # the line is quiet.
            while True:
                try:
                    chunk = ser.read(max(ser.in_waiting, 1))
                except (OSError, serial.SerialException):
                    break  # the emulator closed the pty (hang-up)
                if chunk:
                    received.extend(chunk)
                elif emu.proc.poll() is not None:
                    break

        t = threading.Thread(target=reader)
        t.start()
        t0 = time.monotonic()
        rc = emu.proc.wait(timeout=600)
        wall = time.monotonic() - t0 - 1.0  # minus --delay
        t.join(timeout=30)
        ser.close()
        err = emu.proc.stderr.read().decode()
    finally:
        emu.kill()
    lines = bytes(received).split(b"\r\n")
    seqs = [int(line.split(b",")[1]) for line in lines if line.startswith(b"$PARVA") and b",4,1," in line[:20]]
    expected = [k % 65536 for k in range(frames)]
    return {
        "rc": rc,
        "epochs_per_s": frames / wall,
        "complete": seqs == expected,
        "received": len(seqs),
        "summary": err.strip(),
    }


EFFECT_SCENES = {
    "ideal (no effect)": "",
    "noise": "[effects]\nnoise = true\n",
    "research_sentences": "[effects]\nresearch_sentences = true\n",
}


def effect_costs(tmp: Path, frames: int) -> list[list[str]]:
    rows = []
    base = DEFAULT.replace('name = "paper-case-study"\n', "")
    for name, extra in EFFECT_SCENES.items():
        scene = scene_file(tmp, base + "\n" + extra, f"effect_{len(rows)}.toml")
        # Batch time inside one process, excluding start-up: render `frames` epochs.
        code = (
            "import time, sys\n"
            "from emulator.scene import load_scene\nfrom emulator.streams import scene_streams\n"
            f"s = scene_streams(load_scene({scene!r}))[0]\n"
            "s.render(0, 100)\n"
            f"t = time.perf_counter(); k = 100\n"
            f"while k < {frames} + 100:\n    s.render(k, 1024); k += 1024\n"
            "print((time.perf_counter() - t) / (k - 100))\n"
        )
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        rows.append([name, float(out.stdout)])
    ideal = rows[0][1]
    return [[n, f"{t * 1e6:.2f} µs", f"{t / ideal:.2f}x"] for n, t in rows]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        j = jitter(tmp, 20.0, args.seconds)
        f = fast_with_reader(tmp, args.frames)
        costs = effect_costs(tmp, 50_000)
    t1 = markdown_table(
        ["stream", "epochs", "p50 |dt - 50 ms|", "p99", "max"],
        [["20 Hz, default scene, pty + pyserial reader", j["epochs"], f"{j['p50']:.3f} ms", f"{j['p99']:.3f} ms", f"{j['max']:.3f} ms"]],
    )
    t2 = markdown_table(
        ["run", "epochs/s", "all epochs received, in order", "emulator summary"],
        [[f"--speed 0 --frames {args.frames} to a pty, reader keeping up", f"{f['epochs_per_s']:,.0f}",
          "yes" if f["complete"] else f"NO ({f['received']} received)", f["summary"]]],
    )
    t3 = markdown_table(["scene", "time per epoch (4 tx, 4 channels)", "vs ideal"], costs)
    body = (
        "Real-time precision (target p99 < 2 ms):\n\n" + t1 + "\n\nAs fast as possible (target >= 20,000 epochs/s, "
        "zero loss):\n\n" + t2 + "\n\nWhat each effect costs (render time per epoch, 1024-epoch batches, "
        "start-up excluded):\n\n" + t3
    )
    print(body)
    if not args.no_write:
        write_section("emulator", "Emulator on a pty", body, "python tests/perf/bench_emulator.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
