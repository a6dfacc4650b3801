"""Firmware in the loop, timed (issue 31): QEMU boot, 20 stepped epochs, decisions read back.

Builds the example firmware (firmware_proto/examples/search_fw), then ``RUNS`` times: starts
the board and the emulator (step clock, 10 Hz scene), waits for the firmware's boot line,
steps 20 epochs one at a time (each read back from UART1 before the next) and stops both.
Reports the wall time of the whole loop, of boot (QEMU start to the boot line) and of the
20 epochs, and the bytes lost (captured by the emulator minus counted by the firmware's
decoder), with and without ``-icount``. Rewrites its section of docs/performance.md.

Run alone on an idle machine: ``python tests/perf/bench_firmware_loop.py [--runs 10]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _report import markdown_table, write_section  # noqa: E402

from emulator.testing.qemu import EXAMPLE_FIRMWARE, FirmwareLoop, build_firmware  # noqa: E402

SCENE = {
    "spec": 1,
    "rate_hz": 10.0,
    "transmitters": [{"id": 1, "position": [0.0, 0.0, -1.0]}],
    "receiver": {"channels": 2, "path": [{"t": 0.0, "position": [60.0, 0.0, 0.0]}, {"t": 2.0, "position": [1.0, 0.0, 0.0]}]},
}


def one_run(elf: Path, icount: int | None) -> dict:
    with tempfile.TemporaryDirectory() as work:
        t0 = time.perf_counter()
        loop = FirmwareLoop.start(elf, SCENE, clock="step", workdir=work, icount=icount)
        try:
            loop.board.wait_for(lambda lines: len(lines) >= 1)
            t_boot = time.perf_counter()
            for _ in range(20):
                k = loop.emu.step() - 1
                loop.decision(k)
            t_epochs = time.perf_counter()
            lost = len(loop.captured()) - loop.decisions()[-1]["bytes"]
        finally:
            loop.stop()
        t_end = time.perf_counter()
    return {"whole": t_end - t0, "boot": t_boot - t0, "epochs": t_epochs - t_boot, "lost": lost}


def long_step(elf: Path, n: int = 1000) -> tuple[float, int, int]:
    """One step of ``n`` epochs (two transmitters heard: ~56 bytes an epoch) into the
    firmware's UART: (wall s until its last decision, bytes offered, bytes lost)."""
    scene = {**SCENE, "transmitters": [{"id": 1, "position": [20.0, 0.0, 0.0]}, {"id": 2, "position": [0.0, 25.0, 0.0]}],
             "receiver": {"channels": 2, "position": [0.0, 0.0, 0.0]}}
    with tempfile.TemporaryDirectory() as work:
        loop = FirmwareLoop.start(elf, scene, clock="step", workdir=work)
        try:
            loop.board.wait_for(lambda lines: len(lines) >= 1)
            t0 = time.perf_counter()
            loop.decision(loop.emu.step(n) - 1, timeout=120)
            wall = time.perf_counter() - t0
            offered = len(loop.captured())
            lost = offered - loop.decisions()[-1]["bytes"]
        finally:
            loop.stop()
    return wall, offered, lost


def longest_stall(elf: Path, lines: int = 4000) -> tuple[float, int]:
    """Blocking 16-byte writes of ``lines`` $PARVA lines into QEMU's UART0 pty while the
    firmware reads: (longest single write s, bytes). A write blocks until the pty shows
    room, so this is how long a reader that keeps reading can look idle (the step clock's
    drain wait, emulator.output.scheduler.STEP_DRAIN_WAIT, must exceed it)."""
    import tty

    from emulator.testing.qemu import Board

    data = b"$PARVA,1,1834,45.0,1,0*00\r\n" * lines
    with tempfile.TemporaryDirectory() as work:
        board = Board(elf, work)
        fd = os.open(board.uart0, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            board.wait_for(lambda got: len(got) >= 1)
            worst, off = 0.0, 0
            while off < len(data):
                t = time.perf_counter()
                off += os.write(fd, data[off:off + 16])
                worst = max(worst, time.perf_counter() - t)
        finally:
            os.close(fd)
            board.stop()
    return worst, len(data)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--no-write", action="store_true", help="print only; leave docs/performance.md alone")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as build:
        elf = build_firmware(EXAMPLE_FIRMWARE, build)
        size_line = [ln for ln in (Path(build) / "build.log").read_text().splitlines() if "search_fw.elf" in ln and ln.strip()[0].isdigit()]
        rows = []
        for icount in (None, 4):
            runs = [one_run(elf, icount) for _ in range(args.runs)]
            pick = lambda key: [r[key] for r in runs]  # noqa: E731
            rows.append([
                "off" if icount is None else f"shift={icount}",
                args.runs,
                f"{statistics.median(pick('whole')):.2f} / {max(pick('whole')):.2f}",
                f"{statistics.median(pick('boot')) * 1000:.0f} / {max(pick('boot')) * 1000:.0f}",
                f"{statistics.median(pick('epochs')) * 1000:.0f} / {max(pick('epochs')) * 1000:.0f}",
                sum(pick("lost")),
            ])
        steps = [long_step(elf) for _ in range(3)]
        stalls = [longest_stall(elf) for _ in range(3)]
    header = ["-icount", "runs", "whole loop s (median / max)", "boot ms (median / max)", "20 epochs ms (median / max)", "bytes lost"]
    table = markdown_table(header, rows)
    rate = [offered / wall / 1000 for wall, offered, _ in steps]
    table += (
        f"\n\nOne step of 1000 epochs ({steps[0][1]:,} bytes) into the firmware's UART, 3 runs: "
        f"{', '.join(f'{w:.2f}' for w, _, _ in steps)} s to the last decision "
        f"({min(rate):.1f}-{max(rate):.1f} KB/s: QEMU hands the guest one byte at a time), "
        f"{sum(lost for _, _, lost in steps)} bytes lost. "
        f"Writing {stalls[0][1]:,} bytes into the UART's pty while the firmware reads, the longest "
        f"a write waited for room (the reader looking idle): {', '.join(f'{w:.2f}' for w, _ in stalls)} s "
        "(the step clock's drain wait, 5 s, must exceed it)."
    )
    print(table)
    load = os.getloadavg()[0]
    body = (
        "The whole firmware-in-the-loop cycle of `tests/emulator/testing/test_firmware_loop.py`: QEMU (`-M mps2-an385`) "
        "started with the example firmware, the emulator started on its UART0 (step clock), "
        "the firmware's boot line read, 20 epochs stepped one at a time with each decision read "
        "back from UART1, both stopped. Target: the whole loop <= 5 s on 2 cores; 0 bytes lost. "
        f"Load average at the end: {load:.2f}. Firmware: `{size_line[0].split()[0]}` bytes of text "
        "(arm-none-eabi-gcc -Os).\n\n" + table
    )
    if not args.no_write:
        write_section("firmware_loop", "Firmware in the loop (QEMU)", body, "tests/perf/bench_firmware_loop.py")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
