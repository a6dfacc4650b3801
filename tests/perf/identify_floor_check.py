"""Which recorded study fits the r_en identifiability rule's floor changes
(``bench.fit.identify.R_EN_TYPICAL``, issue 28, item 1; docs/calibration.md,
"Identifiability").

For every converged fit with an r_en and a GPS error in the given study runs (jsonl of
``calibration_study.py``), the campaign is made again (``study_campaigns``, a pure
function of condition and seed) and the rule is evaluated on its rows at the fitted
r_en and GPS error, once as before the floor (at the fitted r_en) and once with it (at
r_en no lower than R_EN_TYPICAL). Prints the fits whose verdict differs and the count.
Rows are at the logged poses (the fit's rows before the pose-error model moves them).

Usage::

    python tests/perf/identify_floor_check.py tests/perf/out/calibration_study_*.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import study_campaigns as sc  # noqa: E402

from bench.fit.csvio import parse_csv  # noqa: E402
from bench.fit.eiv import usable  # noqa: E402
from bench.fit.estimate import check_table  # noqa: E402
from bench.fit.identify import R_EN_TYPICAL, noise_reach  # noqa: E402
from bench.fit.likelihood import Params  # noqa: E402
from bench.fit.result import EIV_FREE, FitOptions  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="calibration_study.py jsonl files")
    args = ap.parse_args(argv)
    checked, changed = 0, []
    for path in args.runs:
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            fit = rec.get("fit") or {}
            if rec.get("status") != "converged" or fit.get("r_en") is None or not fit.get("gps_sigma"):
                continue
            camp = sc.campaign(sc.CONDITIONS[rec["condition"].split(" [")[0]], rec["seed"])
            rows = usable(check_table(parse_csv(camp.csv_text().encode(), path.name), FitOptions(free=EIV_FREE)))
            at = Params(r_en=fit["r_en"], gps_sigma=fit["gps_sigma"])
            before, after = noise_reach(rows, at, floor=0.0).determined, noise_reach(rows, at).determined
            checked += 1
            if before != after:
                changed.append(f"{path.name}: {rec['condition']} seed {rec['seed']}: r_en {fit['r_en']:.1f} m (truth "
                               f"{rec['truth']['r_en']:.1f}), determined {before} -> {after}")
    print("\n".join(changed))
    print(f"{checked} fits checked, {len(changed)} change their r_en verdict with the floor at {R_EN_TYPICAL:g} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
