"""Bench logging (issues 5, 12). Prints tables and writes docs/performance.md.

Every device is a pty fed by a PRE-RENDERED writer (a separate process that only writes
bytes rendered before the clock starts; no emulator), logged by a real `arva-bench log`.

1. Ingest: three receivers, 20 channels each, offered at a fixed summed rate; logged
   sentences/s summed over the three ptys, and zero loss (every epoch logged, in order,
   no decoder error).
2. Skew at 20x real time: a typical session (receiver 1 Hz x 4 channels, GPS 1 Hz
   GGA+RMC, attitude 10 Hz) replayed at 20x; every 50 ms the writer writes the same
   scene instant to the three ptys back to back. Skew = spread of the three devices'
   stamps of one instant (the stamp of each device's last record of that instant, i.e.
   its read's stamp); latency = stamp - the writer's clock after its write (both
   CLOCK_MONOTONIC).
3. Reconnect: a receiver at 100 epochs/s is unplugged (pty closed, the symlink the
   logger opens removed) for 1 s and plugged back (a new pty behind the same symlink);
   what is lost beyond the outage = epochs written after the replug that were never
   logged, plus the time from the replug to the first logged epoch's write.
4. Disk per hour of the typical session, logged at 120x for 30 s.
"""

from __future__ import annotations

import argparse
import datetime as dt
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import markdown_table, publish  # noqa: E402

from bench.session import read_jsonl, read_raw  # noqa: E402
from emulator.frames.geodesy import Origin, enu_to_geodetic  # noqa: E402
from emulator.truth.nmea import gps_sentences, pashr_sentence  # noqa: E402
from firmware_proto.sentences import encode_parva  # noqa: E402

CHANNELS = 20
SKEW_NOTE = ('A spread of a whole number of 0.0868 ms steps (one byte at 115200 Bd: 6.51 ms = 75 bytes, one $PASHR) comes from a read holding two instants of one device: the logger was descheduled for more than 50 ms, and the stamp rule spread the earlier instant back at line rate, which a pty, having no line rate, does not honour.')
ORIGIN = Origin(46.5, 8.0, 2500.0)
START_UTC = 1768471200.0


# -- pre-rendered streams ----------------------------------------------------------------------
def epochs(first: int, count: int, channels: int) -> list[bytes]:
    return [b"".join(encode_parva(k % 65536, channels, s, s, 1000 + k % 500, s % 90) for s in range(1, channels + 1))
            for k in range(first, first + count)]  # fmt: skip


def typical(seconds: float) -> dict[str, list[tuple[float, bytes]]]:
    """Scene-time bursts (s, bytes) of a typical session: receiver 1 Hz x 4 channels,
    GPS 1 Hz GGA+RMC, attitude 10 Hz, all aligned on the 0.1 s grid."""
    out: dict[str, list] = {"arva": [], "gps-rx": [], "attitude-rx": []}
    for j in range(int(seconds * 10)):
        t = j / 10
        utc = dt.datetime.fromtimestamp(START_UTC + t, dt.timezone.utc)
        out["attitude-rx"].append((t, pashr_sentence(utc, (3.0 * t) % 360.0, 1.0, -2.0)))
        if j % 10 == 0:
            k = j // 10
            lat, lon, alt = (float(v) for v in enu_to_geodetic(-40.0 + 0.02 * k, -40.0 + 0.02 * k, 1.0, ORIGIN))
            out["gps-rx"].append((t, gps_sentences(utc, lat, lon, alt)))
            out["arva"].append((t, b"".join(encode_parva(k % 65536, 4, s, s, 2000 - k % 1000, 10 * s) for s in range(1, 5))))
    return out


# -- the writer process --------------------------------------------------------------------------
def _writer(fds: dict[str, int], bursts: list[tuple[float, str, bytes]], speed: float, go, conn) -> None:
    """Writes each burst at t0 + t / speed (speed 0: as fast as the ptys take it); sends
    back the monotonic time after each write."""
    go.wait()
    t0 = time.monotonic()
    done = []
    for t, name, data in bursts:
        if speed > 0:
            delay = t0 + t / speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        view = memoryview(data)
        while view:
            view = view[os.write(fds[name], view):]
        done.append(time.monotonic())
    conn.send((t0, done))
    conn.close()


def openpty_raw() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline before the logger opens it
    return master, slave, os.ttyname(slave)


def log_cmd(paths: dict[str, str], out: Path, duration: float) -> list[str]:
    cmd = [sys.executable, "-m", "bench.cli", "log", "--out", str(out), "--duration", str(duration),
           "--origin", f"{ORIGIN.lat},{ORIGIN.lon},{ORIGIN.alt}"]  # fmt: skip
    for name, path in paths.items():
        kind, _, role = name.partition("-")
        if kind == "arva":
            cmd += ["--arva", path if not role else f"{path},role={role}"]
        else:
            cmd += [f"--{kind}", path]
    return cmd


def wait_opened(pid: int, paths: list[str], timeout: float = 30.0) -> None:
    """Until process ``pid`` has every path open (its /proc fd links)."""
    deadline = time.monotonic() + timeout
    want = {os.path.realpath(p) for p in paths}
    while time.monotonic() < deadline:
        have = set()
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    have.add(os.readlink(f"/proc/{pid}/fd/{fd}"))
                except OSError:
                    pass
        except OSError:
            pass
        if want <= have:
            return
        time.sleep(0.05)
    raise TimeoutError(f"the logger did not open {sorted(want - have)}")


def wait_logged(out: Path, timeout: float = 300.0) -> None:
    """Until the session's files stop growing for 1 s (a loaded machine may leave the
    logger seconds behind the writer; stopping it early would count as loss). Only file
    sizes are polled: parsing the logs meanwhile would slow the logger down."""
    deadline = time.monotonic() + timeout
    last, still = -1, 0
    while time.monotonic() < deadline:
        size = sum(p.stat().st_size for p in out.iterdir()) if out.exists() else 0
        still = still + 1 if size == last else 0
        if still >= 2:
            return
        last = size
        time.sleep(0.5)
    print(f"[{out.name}] the session was still growing after {timeout:g} s", file=sys.stderr)


def run_session(tmp: Path, streams: dict[str, list[tuple[float, bytes]]], speed: float, tag: str, tail: float = 0.5):
    """Log ``streams`` written by a pre-rendered writer; (session dir, writer t0, write times by burst)."""
    ptys = {name: openpty_raw() for name in streams}
    bursts = sorted(((t, name, data) for name, items in streams.items() for t, data in items), key=lambda b: b[0])
    out = tmp / tag
    ctx = mp.get_context("fork")
    go = ctx.Event()
    recv, send = ctx.Pipe(duplex=False)
    writer = ctx.Process(target=_writer, args=({n: p[0] for n, p in ptys.items()}, bursts, speed, go, send))
    writer.start()
    logger = subprocess.Popen(log_cmd({n: p[2] for n, p in ptys.items()}, out, 3600), stderr=subprocess.PIPE, text=True)
    try:
        wait_opened(logger.pid, [p[2] for p in ptys.values()])
        go.set()
        t0, done = recv.recv()
        writer.join(60)
        wait_logged(out)
        time.sleep(tail)
        logger.terminate()
        _, err = logger.communicate(timeout=300)
        if logger.returncode != 0:
            raise RuntimeError(f"log failed: {err}")
        if "Traceback" in err or "did not finish" in err:
            print(f"[{tag}] the logger said:\n{err}", file=sys.stderr)
    finally:
        if logger.poll() is None:
            logger.kill()
        for master, slave, _ in ptys.values():
            os.close(master)
            os.close(slave)
    return out, t0, bursts, np.array(done)


# -- 1. ingest -------------------------------------------------------------------------------------
def ingest(tmp: Path, target: float, seconds: float) -> dict:
    rate = target / (3 * CHANNELS)  # epochs/s per receiver
    frames = int(rate * seconds)
    block = 0.01  # the writer writes 10 ms of epochs at a time
    per_block = max(1, int(round(rate * block)))
    streams = {}
    for name in ("arva-rx1", "arva-rx2", "arva-rx3"):
        eps = epochs(0, frames, CHANNELS)
        streams[name] = [(k / rate, b"".join(eps[k:k + per_block])) for k in range(0, frames, per_block)]
    out, _t0, _bursts, done = run_session(tmp, streams, 1.0, f"ingest-{int(target)}")
    sentences, first, last, complete = 0, float("inf"), 0.0, True
    for name in streams:
        raw = read_raw(out / f"{name}.raw").reads
        sentences += b"".join(r.data for r in raw).count(b"$PARVA")
        first, last = min(first, raw[0].mono), max(last, raw[-1].mono)
        records = list(read_jsonl(out / f"{name}.jsonl"))
        seqs = [r["seq"] for r in records if "seq" in r]
        complete &= seqs == [k % 65536 for k in range(frames)] and not any("error" in r for r in records)
    return {"target": target, "sentences": sentences, "seconds": last - first, "rate": sentences / (last - first),
            "complete": complete, "offered_seconds": float(done[-1] - done[0]) if done.size else 0.0}


# -- 2. skew at 20x -------------------------------------------------------------------------------
def skew(tmp: Path, seconds: float) -> dict:
    streams = typical(seconds)
    out, _t0, bursts, done = run_session(tmp, streams, 20.0, "skew")
    # The logger's stamp of each device's last record of each scene instant.
    stamps: dict[str, dict[float, float]] = {}
    for name, items in streams.items():
        records = [r for r in read_jsonl(out / f"{name}.jsonl") if "error" not in r]
        per = {"arva": 1, "gps-rx": 2, "attitude-rx": 1}[name]  # records per instant
        by_instant = [records[i + per - 1]["mono"] for i in range(0, len(records) - per + 1, per)]
        stamps[name] = {t: m for (t, _), m in zip(items, by_instant)}
    written = {}
    for (t, name, _), w in zip(bursts, done):
        written.setdefault(t, {})[name] = w
    spreads, added, writer_spread, latencies = [], [], [], []
    for t in sorted(stamps["arva"]):
        if all(t in stamps[n] for n in stamps):
            s = [stamps[n][t] for n in stamps]
            w = [written[t][n] for n in stamps]
            lat = [a - b for a, b in zip(s, w)]
            spreads.append(max(s) - min(s))
            writer_spread.append(max(w) - min(w))
            added.append(max(lat) - min(lat))
        for n in stamps:
            if t in stamps[n]:
                latencies.append(stamps[n][t] - written[t][n])
    ms = {k: np.array(v) * 1e3 for k, v in
          (("spread", spreads), ("added", added), ("writer", writer_spread), ("lat", latencies))}  # fmt: skip
    return {"instants": len(spreads), **{f"{k}_{q}": float(np.percentile(v, q)) for k, v in ms.items() for q in (50, 99)},
            "spread_max": float(ms["spread"].max())}


# -- 3. reconnect ---------------------------------------------------------------------------------
def _unplugging_writer(link: str, rate: float, before: int, after: int, outage: float, conn) -> None:
    period = 1.0 / rate
    eps = epochs(0, before + after, 4)
    master, slave, path = openpty_raw()
    os.symlink(path, link)
    conn.send("ready")
    conn.recv()  # the logger has it open
    t0 = time.monotonic()
    for k in range(before):
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
        os.write(master, eps[k])
    os.unlink(link)
    os.close(master)
    os.close(slave)
    unplugged = time.monotonic()
    time.sleep(outage)
    master, slave, path = openpty_raw()
    os.symlink(path, link)
    replug = time.monotonic()
    sent = []
    for j in range(after):
        time.sleep(max(0.0, replug + j * period - time.monotonic()))
        os.write(master, eps[before + j])
        sent.append(time.monotonic())
    time.sleep(1.0)
    conn.send((unplugged, replug, sent))
    conn.recv()
    os.close(master)
    os.close(slave)


def reconnect(tmp: Path, outage: float = 1.0) -> dict:
    rate, before, after = 100.0, 200, 300
    link = str(tmp / "arva-link")
    out = tmp / "reconnect"
    ctx = mp.get_context("fork")
    here, there = ctx.Pipe()
    writer = ctx.Process(target=_unplugging_writer, args=(link, rate, before, after, outage, there))
    writer.start()
    assert here.recv() == "ready"
    logger = subprocess.Popen(log_cmd({"arva": link}, out, 3600), stderr=subprocess.PIPE, text=True)
    try:
        wait_opened(logger.pid, [link])
        here.send("go")
        unplugged, replug, sent = here.recv()
        logger.terminate()
        logger.communicate(timeout=60)
        here.send("done")
        writer.join(10)
    finally:
        if logger.poll() is None:
            logger.kill()
    seqs = {r["seq"] for r in read_jsonl(out / "arva.jsonl") if "seq" in r}
    lost_after = [j for j in range(after) if before + j not in seqs]
    first = min((j for j in range(after) if before + j in seqs), default=None)
    beyond = (len(lost_after) / rate) if first is None else (sent[first] - replug) + len(lost_after) / rate
    return {"outage": outage, "lost_epochs": len(lost_after), "beyond_ms": beyond * 1e3,
            "lost_before": [k for k in range(before) if k not in seqs]}


# -- 4. disk per hour -----------------------------------------------------------------------------
def disk_per_hour(tmp: Path, speed: float, seconds: float) -> dict:
    scene_seconds = speed * seconds
    out, *_ = run_session(tmp, typical(scene_seconds), speed, "typical")
    sizes = {p.name: p.stat().st_size for p in sorted(out.iterdir())}
    hours = scene_seconds / 3600.0
    return {"per_hour": sum(sizes.values()) / hours, "sizes": {k: v / hours for k, v in sizes.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="50000,100000,150000", help="offered sentences/s (summed) to try")
    ap.add_argument("--seconds", type=float, default=5.0, help="length of each ingest run (s of offered data)")
    ap.add_argument("--repeat", type=int, default=3, help="ingest runs per offered rate (the machine's load varies)")
    ap.add_argument("--skew-seconds", type=float, default=600.0, help="scene seconds of the 20x skew run")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        runs = [[ingest(tmp / f"{t}-{i}", float(t), args.seconds) for i in range(args.repeat)
                 if not (tmp / f"{t}-{i}").mkdir()] for t in args.targets.split(",")]  # fmt: skip
        sk = skew(tmp, args.skew_seconds)
        rc = [reconnect(tmp / f"r{i}") for i in range(3) if not (tmp / f"r{i}").mkdir()]
        disk = disk_per_hour(tmp, 120.0, 30.0)
    load_after = os.getloadavg()[0]
    t1 = markdown_table(
        ["offered (sentences/s)", "logged sentences per run", "seconds per run",
         "logged sentences/s (3 ptys summed), each run", "zero loss (every epoch logged, in order; no decoder error)"],
        [[f"{rs[0]['target']:,.0f}", " / ".join(f"{r['sentences']:,}" for r in rs),
          " / ".join(f"{r['seconds']:.2f}" for r in rs), " / ".join(f"{r['rate']:,.0f}" for r in rs),
          "yes" if all(r["complete"] for r in rs) else "NO"] for rs in runs],
    )  # fmt: skip
    t2 = markdown_table(
        ["instants", "stamp spread p50 / p99 / max (ms)", "of it, the writer's own spread p50 / p99 (ms)",
         "logger-added skew p50 / p99 (ms)", "latency p50 / p99 (ms)"],
        [[sk["instants"], f"{sk['spread_50']:.3f} / {sk['spread_99']:.3f} / {sk['spread_max']:.3f}",
          f"{sk['writer_50']:.3f} / {sk['writer_99']:.3f}", f"{sk['added_50']:.3f} / {sk['added_99']:.3f}",
          f"{sk['lat_50']:.3f} / {sk['lat_99']:.3f}"]],
    )  # fmt: skip
    t3 = markdown_table(
        ["run", "outage (s)", "epochs lost after the replug", "lost beyond the outage (ms)",
         "epochs lost before the unplug (seq)"],
        [[i + 1, f"{r['outage']:.1f}", r["lost_epochs"], f"{r['beyond_ms']:.1f}",
          ", ".join(map(str, r["lost_before"])) or "none"] for i, r in enumerate(rc)],
    )  # fmt: skip
    t4 = markdown_table(
        ["file", "MB per hour"],
        [[k, f"{v / 1e6:.2f}"] for k, v in disk["sizes"].items()] + [["**total**", f"**{disk['per_hour'] / 1e6:.2f}**"]],
    )
    body = (
        f"Load average (1 min) {load_before:.1f} before the run, {load_after:.1f} after it (other jobs "
        "sharing the cores lower the throughput and raise the skew). Every device is a pty fed by a "
        "pre-rendered writer process (bytes rendered before the clock starts, no emulator) and logged "
        "by a real `arva-bench log` (one selector loop, `bench.ingest`).\n\n"
        f"Ingest (target >= 150,000 sentences/s summed, zero loss): three receivers x {CHANNELS} channels, "
        f"{args.seconds:.0f} s of epochs offered at each rate in 10 ms blocks, {args.repeat} runs each (the "
        "machine's load varies from run to run). The writer blocks when a pty is full, so a logger that "
        "cannot keep up stretches 'seconds' instead of losing data.\n\n" + t1 +
        "\n\nInter-device stamp skew at 20x real time (target p99 < 1 ms): a typical session (receiver "
        "1 Hz x 4 channels, GPS 1 Hz GGA+RMC, attitude 10 Hz); every 50 ms the writer writes one scene "
        "instant to the three ptys back to back. Stamp spread = max - min of the three devices' stamps "
        "of one instant; part of it is the writer's own (it may lose the CPU between its three writes); "
        "logger-added skew = spread of (stamp - that device's write time); latency = stamp minus the "
        "writer's clock after its write (both CLOCK_MONOTONIC). " + SKEW_NOTE + "\n\n" + t2 +
        "\n\nReconnect (target <= 100 ms lost beyond the outage): a receiver at 100 epochs/s unplugged "
        "for 1 s (pty closed, its symlink removed), then a new pty behind the same symlink.\n\n" + t3 +
        "\n\nDisk per hour of the typical session (raw reads base64 with timestamps plus decoded JSON "
        "lines), logged at 120x for 30 s:\n\n" + t4
    )
    publish("logger", "Bench logging", body, "python tests/perf/bench_logger.py", write=not args.no_write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
