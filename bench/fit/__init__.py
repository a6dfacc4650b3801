"""Calibration of the receiver model from field data (``arva-bench fit``, issue 6).

Modules: :mod:`.table` (the normative table), :mod:`.csvio` (reading it),
:mod:`.special` and :mod:`.likelihood` (the model's distribution of d),
:mod:`.fit` (maximum likelihood and standard errors; :mod:`.worker`, the second process
that evaluates a stencil's points with it), :mod:`.report`, :mod:`.scene`,
:mod:`.campaign` (emulated campaigns) and :mod:`.cli` (the sub-command).

Importing the package stays light (argparse only), because ``arva-bench`` builds every
sub-command's parser at start-up.
"""

from .cli import register, run

__all__ = ["register", "run"]
