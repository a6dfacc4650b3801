"""The table behind docs/calibration.md's r_en identifiability rule: per walk shape of the
calibration study's generator (``study_campaigns.py``, tuning seeds), the fraction and
number of rows within r_outer = 50 m where the EMI noise shows through 1 m of GPS error
(:func:`bench.fit.identify.noise_shows`, at each campaign's true r_en and the logged
distances). No fit: seconds.

Usage: python tests/perf/identify_table.py [SEEDS]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

import study_campaigns as sc  # noqa: E402
from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.identify import noise_shows  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", type=int, nargs="?", default=10, help="tuning seeds 0..SEEDS-1 per walk (default 10)")
    seeds = ap.parse_args().seeds
    for cond in ("radial-gm", "level-gm", "spiral-gm", "near-gm", "far-gm", "drone-gm"):
        frac, rows = [], []
        for seed in range(seeds):
            camp = sc.campaign(sc.CONDITIONS[cond], seed)
            table = parse_csv(camp.csv_text().encode(), f"{cond}-{seed}")
            r = np.linalg.norm(table.rx_pos - table.tx_pos, axis=1)
            r = r[(r > 0) & (r <= 50.0)]
            k = int(np.sum(noise_shows(r, camp.truth.r_en, 1.0)))
            frac.append(k / r.size)
            rows.append(k)
        print(f"{cond:<10} {100 * min(frac):3.0f}-{100 * max(frac):3.0f} %  rows {min(rows)}-{max(rows)}  (seeds 0-{seeds - 1})")


if __name__ == "__main__":
    main()
