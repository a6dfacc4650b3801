"""``arva-bench dash``: the live terminal dashboard (textual).

Modules: ``cli`` (arguments, sources), ``app`` (DashApp), ``widgets``, ``render`` (text
art, no textual), ``state``, ``messages``, ``sources`` (reader threads), ``recorder``
(sessions from the dashboard), ``dash.tcss`` (styles). Textual is imported only when
the dashboard runs, so ``arva-bench --help`` stays fast.
"""

from .cli import register, run

__all__ = ["register", "run"]
