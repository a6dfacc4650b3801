"""Calibration of the receiver model from field data (``arva-bench fit``, issues 6 and 28).

The public API (docs/calibration.md, "Using the fit from Python")::

    from bench.fit import EIV_FREE, FitOptions, fit, read_csv

    result = fit(read_csv("walk.csv"), FitOptions(free=EIV_FREE))
    result.estimate["kappa_eq"], result.se["kappa_eq"], result.converged, result.notes

:func:`fit` (also :data:`fit_table`, its former name) takes a :class:`table.Table` and a
:class:`result.FitOptions` and returns a :class:`result.FitResult`.

Modules, by role:

* input: :mod:`.table` (the normative table, its time-stamp checks), :mod:`.csvio`
  (reading it);
* the model: :mod:`.params` (the parameters, the optimiser's scale and box), :mod:`.rows`
  (outcomes and geometry), :mod:`.special` and :mod:`.likelihood` (the distribution of
  d), :mod:`.pose_error` (how pose error moves each row), :mod:`.eiv` (the rows the fit
  uses);
* the estimate: :mod:`.pilot` (starting values), :mod:`.search` (Newton's method),
  :mod:`.stages` (passes, subsample and all rows), :mod:`.covariance` (standard errors),
  :mod:`.offset` (the clock-offset scan), :mod:`.estimate` (:func:`fit`, tying them
  together), :mod:`.result` (options and result);
* where evaluations run: :mod:`.parallel` (stencil threads) and :mod:`.worker` (the
  second process);
* output: :mod:`.report`, :mod:`.scene`, and :mod:`.cli` (the sub-command).

Importing the package stays light (argparse only), because ``arva-bench`` builds every
sub-command's parser at start-up: the names below load their modules on first use.
"""

from .cli import register, run

__all__ = ["EIV_FREE", "FitInputError", "FitOptions", "FitResult", "Params", "Table", "fit", "fit_table", "read_csv",
           "register", "run"]  # fmt: skip

#: Where each lazily loaded name lives.
_LAZY = {
    "EIV_FREE": "result", "FitOptions": "result", "FitResult": "result", "Params": "params",
    "Table": "table", "FitInputError": "table", "read_csv": "csvio",
}  # fmt: skip


def fit(table, options=None):
    """Fit the receiver model to ``table`` (:func:`estimate.fit`): a :class:`FitResult`."""
    from .estimate import fit as fit_estimate

    return fit_estimate(table, options)


fit_table = fit


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
