"""Decoder throughput (issue 3). Prints a table and writes docs/performance.md.

Usage: python tests/perf/bench_decoder.py [--epochs N]

Streams: N epochs of 3 slots (realistic ids, distances, angles), i.e. 3N $PARVA sentences.
"clean" is exactly what a receiver sends; "10 % garbage" damages one sentence in ten
(a flipped bit, a truncation, or a binary burst / junk line / over-long line in front of
it). Throughput counts the sentences in the input (damaged ones included) per second of
wall time, best of several runs:

* Python: firmware_proto.decoder.Decoder, fed in chunks (65536 / 4096 / 256 bytes), all
  events built (sentences, errors, epochs);
* C: firmware_proto/c/arva_codec.c built now with `cc -O2`, called once per stream through
  ctypes; every event is produced by arva_decoder_next() (the firmware API) and counted.
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))

from _report import markdown_table, write_section  # noqa: E402
from c_codec import CDecoder, find_cc  # noqa: E402

from firmware_proto.decoder import Decoder  # noqa: E402
from firmware_proto.sentences import encode_epoch  # noqa: E402

TARGET_PY = 200_000
TARGET_C_RATIO = 10


def make_streams(n_epochs: int, seed: int = 1) -> tuple[bytes, bytes, int]:
    rng = random.Random(seed)
    clean: list[bytes] = []
    dirty: list[bytes] = []
    for e in range(n_epochs):
        slots = [
            (rng.randrange(0, 10), rng.randrange(0, 5000), rng.randrange(-89, 90)) if rng.random() < 0.8 else (-1, -1, -1)
            for _ in range(3)
        ]
        for line in encode_epoch(e % 65536, slots).splitlines(keepends=True):
            clean.append(line)
            if rng.random() >= 0.10:
                dirty.append(line)
                continue
            kind = rng.randrange(4)
            if kind == 0:  # one flipped bit
                b = bytearray(line)
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
                dirty.append(bytes(b))
            elif kind == 1:  # truncated
                dirty.append(line[: rng.randrange(1, len(line))])
            elif kind == 2:  # binary burst in front
                dirty.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) + line)
            else:  # junk / over-long line in front
                dirty.append(b"$" + b"GARBAGE," * rng.randrange(1, 14) + b"\r\n" + line)
    return b"".join(clean), b"".join(dirty), len(clean)


def best_of(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def python_rate(data: bytes, chunk: int, repeat: int) -> tuple[float, int]:
    result = {}

    def run() -> None:
        dec = Decoder()
        feed = dec.feed
        for i in range(0, len(data), chunk):
            feed(data[i : i + chunk])
        dec.flush()
        result["ok"] = dec.stats.sentences_ok

    return best_of(run, repeat), result["ok"]


def c_rate(data: bytes, repeat: int) -> tuple[float, int]:
    result = {}

    def run() -> None:
        result["ok"] = CDecoder().count(data)

    return best_of(run, repeat), result["ok"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=100_000, help="epochs per stream (3 sentences each)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-write", action="store_true", help="print only, do not touch docs/performance.md")
    args = ap.parse_args()

    clean, dirty, n = make_streams(args.epochs)
    rows = []
    measured = {}

    def add(label: str, impl: str, data: bytes, seconds: float, ok: int, note: str) -> float:
        rate = n / seconds
        rows.append([impl, label, f"{rate:,.0f}", f"{len(data) / seconds / 1e6:,.1f}", f"{ok:,} / {n:,}", note])
        print(f"{impl:7} {label:28} {rate:14,.0f} sentences/s  ({ok} decoded ok)")
        return rate

    for chunk in (65536, 4096, 256):
        sec, ok = python_rate(clean, chunk, args.repeat)
        measured[("py", "clean", chunk)] = add("clean", "Python", clean, sec, ok, f"feed() in {chunk}-byte chunks")
    sec, ok = python_rate(dirty, 65536, args.repeat)
    measured[("py", "dirty", 65536)] = add("10 % garbage", "Python", dirty, sec, ok, "feed() in 65536-byte chunks")

    c_note = None
    if find_cc() is None:
        c_note = "no C compiler found: C decoder not measured"
        print(c_note)
    else:
        sec, ok = c_rate(clean, args.repeat)
        measured[("c", "clean")] = add("clean", "C", clean, sec, ok, "`cc -O2`, one arva_decoder_next() per event")
        sec, ok = c_rate(dirty, args.repeat)
        measured[("c", "dirty")] = add("10 % garbage", "C", dirty, sec, ok, "`cc -O2`, one arva_decoder_next() per event")

    py_clean = measured[("py", "clean", 65536)]
    summary = (
        f"Targets (issue 3): Python >= {TARGET_PY:,} sentences/s on a clean stream; C >= {TARGET_C_RATIO}x Python. "
        f"Measured: Python {py_clean:,.0f} sentences/s clean (65536-byte chunks), "
        f"{measured[('py', 'dirty', 65536)]:,.0f} with 10 % garbage"
    )
    if ("c", "clean") in measured:
        summary += (
            f"; C {measured[('c', 'clean')]:,.0f} clean = {measured[('c', 'clean')] / py_clean:,.0f}x Python, "
            f"{measured[('c', 'dirty')]:,.0f} with 10 % garbage = "
            f"{measured[('c', 'dirty')] / measured[('py', 'dirty', 65536)]:,.0f}x Python."
        )
    else:
        summary += f"; {c_note}."
    print(summary)
    body = (
        f"Streams of {args.epochs:,} epochs x 3 slots = {n:,} `$PARVA` sentences ({len(clean) / 1e6:.1f} MB clean). "
        "\"10 % garbage\": one sentence in ten damaged (flipped bit, truncation, binary burst or junk / "
        "over-long line in front). Sentences/s counts every input sentence, damaged or not; best of "
        f"{args.repeat} runs.\n\n"
        + markdown_table(["decoder", "stream", "sentences/s", "MB/s", "decoded ok", "how"], rows)
        + "\n\n"
        + summary
    )
    if not args.no_write:
        write_section("decoder", "Sentence decoder throughput", body, "python tests/perf/bench_decoder.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
