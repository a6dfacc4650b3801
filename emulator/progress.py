"""Progress on long work (a sweep, a replay, an export, a fit), drawn with rich on stderr
only when stderr is a terminal.

With stderr redirected :func:`progress` yields a tracker whose methods do nothing; on
a terminal the bar is transient and stdout is never redirected, so data piped from
stdout stays byte for byte what it was (stderr lines printed meanwhile appear above the
bar). In ``emulator`` so that ``arva-sweep`` and ``arva-bench`` can both import it.

Units are the caller's: ``advance(n)`` adds ``n`` of ``unit`` (runs, seconds of session
time, rows); ``note`` is a free text column (e.g. ``1,234x real time``).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager


class Tracker:
    """What :func:`progress` yields. The base class is the disabled one: every method
    is a no-op, so callers never test whether a bar is shown."""

    enabled = False

    def advance(self, n: float = 1, note: str | None = None) -> None:
        """Add ``n`` units of work done; optionally replace the note."""

    def update(self, completed: float | None = None, total: float | None = None,
               description: str | None = None, note: str | None = None) -> None:
        """Set absolute values (``completed`` of ``total``), the description or the note."""


class _RichTracker(Tracker):
    enabled = True

    def __init__(self, bar, task) -> None:
        self._bar = bar
        self._task = task

    def advance(self, n: float = 1, note: str | None = None) -> None:
        if note is None:
            self._bar.advance(self._task, n)
        else:
            self._bar.update(self._task, advance=n, note=note)

    def update(self, completed=None, total=None, description=None, note=None) -> None:
        fields = {} if note is None else {"note": note}
        self._bar.update(self._task, completed=completed, total=total, description=description, **fields)


def _columns(unit: str):
    """The count (``12/40 runs``; ``12 runs`` without a total; nothing for a stage that
    counts nothing) and the ETA (only with a total)."""
    from rich.progress import ProgressColumn, TimeRemainingColumn
    from rich.text import Text

    class CountColumn(ProgressColumn):
        def render(self, task) -> Text:
            if task.total is None and not task.completed:
                return Text("")
            done = f"{task.completed:,.0f}"
            text = done if task.total is None else f"{done}/{task.total:,.0f}"
            return Text(f"{text} {unit}".rstrip())

    class EtaColumn(TimeRemainingColumn):
        def render(self, task) -> Text:
            return Text("") if task.total is None else Text("ETA ") + super().render(task)

    return CountColumn(), EtaColumn()


@contextmanager
def progress(description: str, total: float | None = None, unit: str = "", stream=None,
             enabled: bool | None = None) -> Iterator[Tracker]:
    """A transient progress bar on ``stream`` (default stderr) while the block runs.

    ``enabled`` defaults to "``stream`` is a terminal"; disabled, the tracker is a no-op
    and rich is not even imported. ``total`` None draws an indeterminate bar.
    """
    stream = sys.stderr if stream is None else stream
    if enabled is None:
        try:
            enabled = stream.isatty()
        except (AttributeError, ValueError):  # closed or not a real file
            enabled = False
    if not enabled:
        yield Tracker()
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(file=stream, force_terminal=True)
    count, eta = _columns(unit)
    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        count,
        TextColumn("{task.fields[note]}"),
        TimeElapsedColumn(),
        eta,
        console=console,
        transient=True,
        redirect_stdout=False,  # stdout may be data (a pipe): never touch it
        redirect_stderr=stream is sys.stderr,
    )
    with bar:
        task = bar.add_task(description, total=total, note="")
        yield _RichTracker(bar, task)
