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
