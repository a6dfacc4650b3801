"""Emulator on a pty (issues 4, 20). Prints tables and writes docs/performance.md.

1. Real-time precision: 20 Hz epochs for ``--seconds`` (20 s: 400 epochs) per row, under a
   synthetic load this script creates (``--load`` busy processes at normal priority, 2 by
   default: "a loaded 2-core host" made reproducible); p50/p99/max of |arrival interval -
   50 ms| of the first sentence of every epoch, taken at two places:
   * at a pty reader (pyserial, what a device under test sees): includes the kernel's pty
     flip-buffer work, which runs in an ordinary-priority kworker (events_unbound);
   * at a pipe reader (``--port -``, reader SCHED_FIFO): a pipe wakes its reader inside the
     emulator's write() call, so this is the emulator's own write timing (+ ~10 us).
   One pty row runs without the synthetic load, for reference.
2. As fast as possible with a reader keeping up: epochs/s, and every epoch received.
3. What each effect costs: time per epoch of the ideal scene and with one effect on.
"""

from __future__ import annotations

import argparse
import os
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
from emulator.output.realtime import PRIORITY as RT_PRIORITY  # noqa: E402
from emulator.testing import EmulatorProcess  # noqa: E402

DEFAULT = (ROOT / "emulator" / "scenes" / "default.toml").read_text()


def scene_file(tmp: Path, text: str, name: str = "scene.toml") -> str:
    path = tmp / name
    path.write_text(text)
    return str(path)


class SyntheticLoad:
    """``count`` busy-looping processes at normal priority (nice 0) while in the block.

    The real-time rows run under this load, so "a loaded 2-core host" is the same every
    run (two CPU-bound tasks competing with the emulator and the reader for the 2 cores),
    whatever else the machine is doing. Each child is stopped (by its pid) on exit.
    """

    def __init__(self, count: int) -> None:
        self.count = count
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> "SyntheticLoad":
        def normal_priority() -> None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, 0)  # undo an inherited `nice` where permitted
            except OSError:
                pass

        for _ in range(self.count):
            self.procs.append(subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=normal_priority))
        time.sleep(0.5)  # let them start spinning
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait(timeout=10)
        self.procs.clear()


def jitter(tmp: Path, rate_hz: float, seconds: float, realtime: bool = False) -> dict:
    """``realtime``: the emulator runs with --realtime and this reader asks for SCHED_FIFO
    too (restored after), so the measurement is not the reader's own wake-up latency."""
    scene = scene_file(tmp, DEFAULT.replace("rate_hz = 1.0", f"rate_hz = {rate_hz}"))
    frames = int(rate_hz * seconds)
    extra = ("--realtime",) if realtime else ()
    log = tmp / "timing.csv"
    emu = EmulatorProcess("--scene", scene, "--port", "pty", "--frames", str(frames), "--delay", "1",
                          "--timing-log", str(log), *extra)
    arrivals = []
    policy = os.sched_getscheduler(0), os.sched_getparam(0)
    reader_rt = False
    if realtime:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
            reader_rt = True
        except OSError:
            pass
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
        emu.wait(timeout=30)  # writes the timing log at exit
    finally:
        if reader_rt:
            os.sched_setscheduler(0, *policy)
        emu.kill()
    writes = np.loadtxt(log, delimiter=",", skiprows=1, usecols=(3, 4), ndmin=2)
    return {"reader_rt": reader_rt, "reader": _interval_stats(arrivals, rate_hz),
            "write": _interval_stats(writes[:, 0], rate_hz), "write_max_ms": float(np.max(writes[:, 1] - writes[:, 0]) * 1e3)}


def _interval_stats(times, rate_hz: float) -> dict:
    """p50 / p99 / max of |interval - 1/rate| in ms over consecutive epochs."""
    dev_ms = np.abs(np.diff(np.asarray(times)) - 1.0 / rate_hz) * 1000.0
    return {"epochs": len(times), "p50": float(np.percentile(dev_ms, 50)),
            "p99": float(np.percentile(dev_ms, 99)), "max": float(dev_ms.max())}


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
        rc = emu.wait(timeout=600)
        wall = time.monotonic() - t0 - 1.0  # minus --delay
        t.join(timeout=30)
        ser.close()
        err = emu.stderr()
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
    "pulses": "[effects]\npulses = true\n",
    "quantize (leds5)": '[effects]\nquantize = true\n[quantize]\nprofile = "leds5"\n',
    "link_faults (loss, corrupt, split)": "[effects]\nlink_faults = true\n[link_faults]\nloss = 0.01\ncorrupt = 0.01\nsplit = 0.1\n",
    "research_sentences ($PARVH)": "[effects]\nresearch_sentences = true\n",
}

GPS = """
[origin]
lat = 46.5
lon = 8.0
[ground_truth]
gps_rate_hz = 1.0
"""


class _NullPort:
    label = "null"
    bytes_dropped = 0

    def write(self, data):
        return len(data)


def _time_per_epoch(render, frames: int, batch: int = 1024, repeat: int = 3) -> float:
    """Best of ``repeat`` runs of ``frames`` epochs in ``batch``-epoch calls (epochs in
    order, as the scheduler renders them)."""
    render(0, 100)  # warm-up (imports, caches)
    k = 100
    best = float("inf")
    for _ in range(repeat):
        k0 = k
        t0 = time.perf_counter()
        while k < k0 + frames:
            render(k, batch)
            k += batch
        best = min(best, (time.perf_counter() - t0) / (k - k0))
    return best


def effect_costs(frames: int) -> list[list[str]]:
    """Render time per epoch of the default scene's receiver stream, ideal and with one
    effect on; link faults are timed through a FaultyPort writing to a null port, and the
    ground-truth error on the GPS stream it perturbs (compared with that stream ideal)."""
    from emulator.output.link_faults import FaultyPort
    from emulator.scene.reader import loads_scene
    from emulator.pipeline import scene_streams

    base = DEFAULT.replace('name = "paper-case-study"\n', "")
    rows = []
    for name, extra in EFFECT_SCENES.items():
        scene = loads_scene(base + "\n" + extra, name)
        stream = scene_streams(scene)[0]
        render = stream.render
        if scene.effects.link_faults is not None:
            port = FaultyPort(_NullPort(), scene.effects.link_faults, scene.seed, sleep=lambda _s: None, clock=lambda: 0.0)
            render = lambda k, n, _r=stream.render, _p=port: _p.write(_r(k, n))  # noqa: E731
        rows.append([name, _time_per_epoch(render, frames)])
    ideal = rows[0][1]
    out = [[n, f"{t * 1e6:.2f} µs", f"{t / ideal:.2f}x"] for n, t in rows]
    gps_scene = base.replace("[receiver]", "[receiver]\ngps = true") + GPS
    gps_ideal = scene_streams(loads_scene(gps_scene, "gps"))[1]
    gps_error = scene_streams(
        loads_scene(
            gps_scene + "[effects]\nground_truth_error = true\n[ground_truth_error]\ngps_sigma_m = [1.0, 1.0, 2.0]\n",
            "gps-err",
        )
    )[1]
    t_ideal = _time_per_epoch(gps_ideal.render, frames // 10)
    t_err = _time_per_epoch(gps_error.render, frames // 10)
    out.append(["GPS stream (RMC + GGA), ideal", f"{t_ideal * 1e6:.2f} µs", "(own baseline)"])
    out.append(["GPS stream with ground_truth_error", f"{t_err * 1e6:.2f} µs", f"{t_err / t_ideal:.2f}x GPS"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="per real-time row (20 Hz)")
    ap.add_argument("--load", type=int, default=2, help="busy processes at normal priority during the loaded rows")
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        load0 = os.getloadavg()[0]
        runs.append(("`--realtime`", "none added", jitter(tmp, 20.0, args.seconds, realtime=True), os.getloadavg()[0]))
        with SyntheticLoad(args.load):
            for label, rt in (("plain", False), ("`--realtime`", True)):
                runs.append((label, f"{args.load} busy processes", jitter(tmp, 20.0, args.seconds, realtime=rt),
                             os.getloadavg()[0]))
        f = fast_with_reader(tmp, args.frames)
        costs = effect_costs(50_000)
    rows = []
    for label, load, x, after in runs:
        reader = "pty reader (pyserial), " + ("SCHED_FIFO" if x["reader_rt"] else "normal priority")
        for where, st in (("emulator's write() (`--timing-log`)", x["write"]), (reader, x["reader"])):
            rows.append([label, load, where, st["epochs"], f"{st['p50']:.3f} ms", f"{st['p99']:.3f} ms",
                         f"{st['max']:.3f} ms", f"{after:.1f}"])
    t1 = markdown_table(
        ["emulator, 20 Hz, default scene, pty", "synthetic load", "interval measured at", "epochs",
         "p50 of abs(dt - 50 ms)", "p99", "max", "load average after"],
        rows,
    )
    t2 = markdown_table(
        ["run", "epochs/s", "all epochs received, in order", "emulator summary"],
        [[f"--speed 0 --frames {args.frames} to a pty, reader keeping up", f"{f['epochs_per_s']:,.0f}",
          "yes" if f["complete"] else f"NO ({f['received']} received)", f["summary"]]],
    )
    if not f["complete"]:
        t2 += (
            "\n\nBytes are dropped when a full pty stays full for `FAST_DRAIN_WAIT` (50 ms, "
            "emulator/output/scheduler.py): the emulator now outruns the reader, so the pty is "
            "full most of the time, and a stall of the reader (a thread of this script, on a "
            "host shared with other jobs) longer than that loses the batch being written."
        )
    t3 = markdown_table(["scene (default scene + one effect)", "time per epoch (4 tx, 4 channels)", "vs ideal"], costs)
    body = (
        "Real-time precision (targets: p99 < 2 ms, issue 4; p99 < 0.5 ms at 20 Hz on a loaded 2-core "
        f"host, issue 20). Load: this script's {args.load} busy processes at normal priority on top of "
        f"whatever else ran (load average {load0:.1f} at the start). Each row is one run of "
        f"{args.seconds:g} s:\n\n" + t1 + "\n\n"
        "Where the error comes from. Each run gives two rows: the emulator's own timing (the "
        "start of each epoch's write() on the pty master, logged by `--timing-log`: sleep to 1 ms "
        "before the deadline, then spin; `--realtime`: SCHED_FIFO + mlockall, "
        "emulator/output/realtime.py), and the arrival at a reader of the pty (what a device "
        "under test sees). Between the two, the kernel pushes the bytes through the pty's flip "
        "buffer in a kworker of the events_unbound workqueue, at ordinary priority: with every "
        "core busy it waits for a CFS time slice (milliseconds), whatever the emulator's "
        "priority, and the reader's own wake-up adds to it (on this 2-vCPU VM even a SCHED_FIFO "
        "reader of a plain pipe sees rare ms-scale delays while the writer's log is clean). The "
        "emulator cannot raise that kworker; host settings can (fewer CPU-bound tasks, or an "
        "isolated core for emulator, reader and the unbound-workqueue cpumask). A real "
        "USB-serial adapter's transmit path has no such worker. Some runs also show stalls of "
        "50-100 ms in the emulator's own write log despite SCHED_FIFO, a few seconds apart, "
        "with or without the synthetic load and with no other real-time task on the host; "
        "their cause is not established (the VM's vCPU scheduling is suspected: a bare "
        "SCHED_FIFO sleep-and-spin loop in the same conditions stays within ~4 ms), and when "
        "they occur they set that run's p99 and max. One run per row: rerun to see the spread.\n\n"
        "As fast as possible (target >= 20,000 epochs/s, zero loss):\n\n" + t2 + "\n\nWhat each effect costs "
        "(render time per epoch, 1024-epoch batches, start-up excluded):\n\n" + t3
    )
    print(body)
    if not args.no_write:
        write_section("emulator", "Emulator on a pty", body, "python tests/perf/bench_emulator.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
