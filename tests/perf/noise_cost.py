"""What line noise costs (issue 29): session size per byte of noise, and the peak memory
and time of export, fit and replay reading a session full of it. Prints a table (the
figures of docs/reliability.md, "Line noise").

    python tests/perf/noise_cost.py                 # 4 MiB and 60 MB of '$'
    python tests/perf/noise_cost.py --mib 1 4 --code /tmp/base   # the same with the code in /tmp/base

``--code DIR`` puts DIR first on PYTHONPATH of every measured process (e.g. an export of
an older commit: ``git archive COMMIT | tar -x -C DIR``), to measure before and after.
Each measurement is a fresh process; peak RSS is its ``ru_maxrss``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mib", type=float, nargs="+", default=[4, 60 / 1.048576], help="noise sizes in MiB")
    ap.add_argument("--code", type=Path, help="measure the code in this directory (PYTHONPATH first)")
    ap.add_argument("--timeout", type=float, default=1800.0)
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
