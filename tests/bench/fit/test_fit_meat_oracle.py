"""The time-block meat of the sandwich (:func:`bench.fit.covariance.time_block_meat`)
against statsmodels' Newey-West HAC sum (``S_hac_simple``, Bartlett weights) as the
oracle: the same matrix for the per-second sums of the scores, with seconds without rows
as zeros and consecutive seconds with rows at most MEAT_GAP apart."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.fit.covariance import MEAT_GAP, time_block_meat

sandwich = pytest.importorskip("statsmodels.stats.sandwich_covariance")


def per_second(scores, t, gap_to=None):
    """The demeaned per-second sums, written out row by row (seconds from the first
    stamp; ``gap_to``: (second, shortened by) for a long gap)."""
    sec = np.floor(t - t.min()).astype(int)
    if gap_to is not None:
        at, by = gap_to
        sec = np.where(sec >= at, sec - by, sec)
    x = np.zeros((sec.max() + 1, scores.shape[1]))
    for s, row in zip(sec, scores):
        x[s] += row
    return x - x.mean(axis=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(30, 600), p=st.integers(1, 4), rho=st.floats(0.0, 0.95))
def test_meat_is_statsmodels_newey_west(seed, n, p, rho):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, n, size=2 * n))  # about two rows a second, some seconds empty
    e = rng.standard_normal((2 * n, p))
    scores = np.empty_like(e)
    scores[0] = e[0]
    for i in range(1, 2 * n):  # correlated in time, as pose error makes them
        scores[i] = rho * scores[i - 1] + e[i]
    meat, lag = time_block_meat(scores, t)
    oracle = sandwich.S_hac_simple(per_second(scores, t), nlags=int(np.floor(lag)))
    np.testing.assert_allclose(meat, oracle, rtol=1e-9, atol=1e-9 * np.abs(oracle).max())


def test_a_gap_longer_than_meat_gap_counts_as_meat_gap():
    rng = np.random.default_rng(3)
    t = np.concatenate([np.arange(0, 2000.0), np.arange(2000.0 + 10_000, 2000.0 + 10_000 + 3000)])
    scores = rng.standard_normal((t.size, 2))
    meat, lag = time_block_meat(scores, t)
    # seconds 1999 and 12000 hold rows: 10,001 s apart, shortened to MEAT_GAP
    x = per_second(scores, t, gap_to=(2000 + 10_000, 10_001 - MEAT_GAP))
    assert x.shape[0] == 1999 + MEAT_GAP + 3000
    np.testing.assert_allclose(meat, sandwich.S_hac_simple(x, nlags=int(np.floor(lag))), rtol=1e-9)
