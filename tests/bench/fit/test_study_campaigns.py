"""The validation study's campaign generator (tests/perf/study_campaigns.py) is independent
of our code, so it must be checked against it once: its own transcription of BRIEF 3 gives
the emulator's integers, and a campaign is a pure function of (condition, seed)."""

import sys

import numpy as np
import repo_paths

sys.path.insert(0, str(repo_paths.PERF))

import study_campaigns as sc  # noqa: E402

from emulator.receiver.model import ModelParams, measure  # noqa: E402


def test_model_transcription_matches_the_emulator():
    rng = np.random.default_rng(5)
    n = 5000
    rx = rng.uniform(-45.0, 45.0, (n, 3))
    rq = rng.normal(size=(n, 4))
    rq /= np.linalg.norm(rq, axis=1)[:, None]
    tp = np.array([[1.0, 2.0, -1.0]])
    tq = np.array([[0.9, 0.1, -0.2, 0.3]]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
    d, delta = sc.receiver_model(rx, rq, np.repeat(tp, n, 0), np.repeat(tq, n, 0), sc.Truth(1.6, 80.0))
    m = measure(rx, rq, tp, tq, ModelParams(kappa_eq=1.6, r_en=80.0))
    assert int((d >= 0).sum()) > 1000
    assert np.array_equal(d, m.d[:, 0]) and np.array_equal(delta, m.delta[:, 0])


def test_campaign_is_a_function_of_condition_and_seed():
    cond = sc.CONDITIONS["level-gm-junk"]
    a, b = sc.campaign(cond, 3), sc.campaign(cond, 3)
    assert np.array_equal(a.rows, b.rows) and a.truth == b.truth
    assert not np.array_equal(sc.campaign(cond, 4).rows[:100], a.rows[:100])
    t = a.rows[:, 0]
    assert np.all(np.diff(t) >= 0)  # gaps and duplicates, never backwards
    assert int((np.diff(t) == 0).sum()) == int(round(0.01 * (len(a.rows) - (np.diff(t) == 0).sum())))
    assert a.csv_text().splitlines()[0] == sc.HEADER


def _record(condition, seed, kz, rz, extra=(), notes=(), status="converged"):
    """A calibration_study record whose kappa_eq and r_en are kz and rz standard errors off."""
    return {
        "condition": condition, "seed": seed, "extra": list(extra), "status": status, "wall": 1.0,
        "started": "2026-12-05 11:00 UTC", "truth": {"kappa_eq": 1.5, "r_en": 80.0}, "notes": list(notes),
        "fit": {"kappa_eq": 1.5 + kz * 0.01, "kappa_eq_se": 0.01, "r_en": 80.0 + rz * 1.0, "r_en_se": 1.0,
                "separable": True},
    }


def test_study_docs_table_takes_each_row_from_its_newest_run(tmp_path):
    import json

    import calibration_study as cs

    old = [_record("level-gm", s, 4.0, 0.0) for s in range(4)]
    new = [_record("level-gm", s, 0.5, 3.5 if s == 0 else 0.0) for s in range(4)]
    new += [_record("level-gm", s, 0.0, 0.0, extra=["--fit", "gps_outlier"], status="not_converged") for s in range(2)]
    new += [_record("far-exact", s, 0.0, -5.0, notes=["the pose-error model does not describe this walk"])
            for s in range(3)]
    for name, recs in (("old.jsonl", old), ("new.jsonl", new)):
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in recs))
    rows = cs.report_records((cs.ReportRun("old.jsonl", "aaaaaaa"), cs.ReportRun("new.jsonl", "bbbbbbb")), tmp_path)
    assert list(rows) == ["level-gm", "level-gm [--fit gps_outlier]", "far-exact"]
    assert {label: (run.commit, len(recs)) for label, (run, recs) in rows.items()} == {
        "level-gm": ("bbbbbbb", 4), "level-gm [--fit gps_outlier]": ("bbbbbbb", 2), "far-exact": ("bbbbbbb", 3)}
    block = cs.docs_block(rows)
    assert "| level-gm | level_rw, gm | bbbbbbb | 2026-12-05 11:00 | 4 | 100 | 0 |" in block
    # one silent miss (r_en z 3.5, no note); far-exact's misses carry a warning note
    assert "Silent misses: 1." in block
    assert "level-gm [--fit gps_outlier]" in block.split("under 99 % converged:")[1].split(".")[0]
    assert "7 converged fits" in block and "0.0 would be expected" in block
