"""Fixtures of the fit tests."""

import copy

import pytest

from bench.fit import estimate


@pytest.fixture
def fit_once_calls(monkeypatch):
    """Every :func:`bench.fit.estimate.fit_once` that :func:`~bench.fit.estimate.fit` makes,
    in order, as (options, a copy of the result as it returned it); the results themselves
    are passed on unchanged. ``fit``'s first call is its first search, the one a test
    would otherwise repeat with ``fit_once(table, options)`` (5 s of CPU on a study
    campaign): the same function on the same table and options."""
    calls: list = []
    real = estimate.fit_once

    def recorded(table, options):
        res = real(table, options)
        calls.append((options, copy.deepcopy(res)))
        return res

    monkeypatch.setattr(estimate, "fit_once", recorded)
    return calls
