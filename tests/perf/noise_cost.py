"""What line noise costs (issue 29): session size per byte of noise, and the peak memory
and time of export, fit and replay reading a session full of it. Prints a table (the
figures of docs/reliability.md, "Line noise").

    python tests/perf/noise_cost.py                 # 4 MiB and 60 MB of '$' (4 MiB also through a pty)
    python tests/perf/noise_cost.py --mib 1 4 --code /tmp/base   # the same with the code in /tmp/base

``--code DIR`` puts DIR first on PYTHONPATH of every measured process (e.g. an export of
an older commit: ``git archive COMMIT | tar -x -C DIR``), to measure before and after.
Each measurement is a fresh process; peak RSS is its ``ru_maxrss``.
"""

from __future__ import annotations

import argparse
import os
import pty
import shutil
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parent)]  # the repository before tests/ (tests/emulator has no __init__.py)

from noise_sessions import peak_rss  # noqa: E402

LOG = """
import json, sys
from pathlib import Path
from noise_sessions import log_noise
summary = log_noise(Path(sys.argv[1]), int(sys.argv[2]))
print(json.dumps(summary), file=sys.stderr)
"""
MAKE = """
import sys
from pathlib import Path
from noise_sessions import noise_session
noise_session(Path(sys.argv[1]), int(sys.argv[2]))
"""


def size(directory: Path) -> int:
    return sum(p.stat().st_size for p in directory.iterdir())


def log_through_pty(out: Path, n: int, env: dict, root: Path, timeout: float) -> tuple[int, str, int, float]:
    """The real ``arva-bench log`` reading a pty into which ``n`` bytes of '$' are written
    (as fast as the pty takes them, after 2 s), for 8 s beyond the time that takes."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    duration = 10.0 + n / 1e6  # a pty carries several MB/s; the logger decodes about 1 MB/s

    def write() -> None:
        time.sleep(2.0)
        sent = 0
        while sent < n:
            sent += os.write(master, b"$" * min(4096, n - sent))

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    try:
        return peak_rss(["log", "--arva", os.ttyname(slave), "--out", str(out), "--duration", f"{duration:g}"],
                        timeout, env=env, cwd=root)  # fmt: skip
    finally:
        writer.join(timeout)
        os.close(master)
        os.close(slave)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mib", type=float, nargs="+", default=[4, 60 / 1.048576], help="noise sizes in MiB")
    ap.add_argument("--code", type=Path, help="measure the code in this directory (PYTHONPATH first)")
    ap.add_argument("--timeout", type=float, default=1800.0)
    ap.add_argument("--pty-max-mib", type=float, default=8.0, help="also log through a pty up to this size (MiB)")
    args = ap.parse_args()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(([str(args.code)] if args.code else []) + [str(HERE.parent)])
    root = Path(tempfile.mkdtemp(prefix="noise-cost-"))  # also the working directory: not a source tree
    probe = "import bench, sys; print(bench.__file__, file=sys.stderr)"
    print(f"load average {os.getloadavg()[0]:.2f}; code: {peak_rss([probe], how=('-c',), env=env, cwd=root)[1].strip()}")
    print("| noise | step | exit | peak RSS (MB) | time (s) | session / noise |")
    print("|---|---|---|---|---|---|")
    notes = []
    try:
        for mib in args.mib:
            n = int(mib * (1 << 20))
            label = f"{n / 1e6:.1f} MB"
            logged = root / f"log-{n}"
            code, err, kb, secs = peak_rss([LOG, str(logged), str(n)], args.timeout, how=("-c",), env=env, cwd=root)
            ratio = f"{size(logged) / n:.3f}" if code == 0 else "-"
            print(f"| {label} | log (listener) | {code} | {kb / 1024:.0f} | {secs:.1f} | {ratio} |", flush=True)
            shutil.rmtree(logged, ignore_errors=True)
            if n <= args.pty_max_mib * (1 << 20):
                code, err, kb, secs = log_through_pty(logged, n, env, root, args.timeout)
                ratio = f"{size(logged) / n:.3f}" if code == 0 else "-"
                print(f"| {label} | arva-bench log (a pty) | {code} | {kb / 1024:.0f} | {secs:.1f} | {ratio} |", flush=True)
                notes.append(f"{label} arva-bench log: {err.strip().splitlines()[0] if err.strip() else ''}")
                shutil.rmtree(logged, ignore_errors=True)
            session = root / f"session-{n}"
            peak_rss([MAKE, str(session), str(n)], args.timeout, how=("-c",), env=env, cwd=root)
            for name, argv in (
                ("export", ["export", str(session), "--csv", str(root / "out.csv")]),
                ("fit", ["fit", str(session)]),
                ("replay", ["replay", str(session), "--speed", "0", "--port", "pty"]),
            ):
                code, err, kb, secs = peak_rss(argv, args.timeout, env=env, cwd=root)
                print(f"| {label} | {name} | {code} | {kb / 1024:.0f} | {secs:.1f} | |", flush=True)
                if code:
                    notes.append(f"{label} {name}: {err.strip().splitlines()[-1] if err.strip() else '(no message)'}")
            shutil.rmtree(session, ignore_errors=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    for note in notes:
        print(note)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
