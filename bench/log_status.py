"""The live table ``arva-bench log`` keeps on a terminal's stderr (rich).

One row per device: link up/down, record and byte rates over the last
:data:`WINDOW` seconds (so a device that stalls shows 0/s within seconds, not a
slowly decaying session average), totals, decoder errors, gaps, and time since its
last data. The main thread calls :meth:`LiveStatus.update` four times a second; it only
reads the counters of the ingest's :class:`~bench.ingest.reader.Device` objects (ints
written by the ingest's work thread as it decodes each read: a torn read is impossible).
"""

from __future__ import annotations

import time
from collections import deque

#: Seconds of history behind each rate.
WINDOW = 5.0
COLUMNS = ("device", "link", "rate", "bytes/s", "records", "errors", "gaps", "last data")


def si(value: float, unit: str) -> str:
    """``1234.5, "B/s"`` -> ``"1.2 kB/s"``: three significant figures at most."""
    for prefix in ("", "k", "M", "G"):
        if abs(value) < 999.5 or prefix == "G":
            break
        value /= 1000.0
    text = f"{value:.1f}" if abs(value) < 99.95 else f"{value:.0f}"
    return f"{text} {prefix}{unit}"


class LiveStatus:
    """Rates and the table for a list of :class:`~bench.ingest.reader.Device`."""

    def __init__(self, loggers, window: float = WINDOW) -> None:
        self.loggers = loggers
        self.window = window
        self._history: dict[str, deque] = {lg.spec.name: deque() for lg in loggers}

    def sample(self, now: float) -> None:
        """Record every device's counters at monotonic time ``now``."""
        for lg in self.loggers:
            h = self._history[lg.spec.name]
            h.append((now, lg.stats.records, lg.stats.bytes))
            while len(h) > 2 and now - h[1][0] >= self.window:
                h.popleft()  # keep one sample at or beyond the window's start

    def rates(self, name: str) -> tuple[float, float] | None:
        """(records/s, bytes/s) of device ``name`` over the window; None before two samples."""
        h = self._history[name]
        if len(h) < 2 or h[-1][0] <= h[0][0]:
            return None
        (t0, r0, b0), (t1, r1, b1) = h[0], h[-1]
        return (r1 - r0) / (t1 - t0), (b1 - b0) / (t1 - t0)

    def rows(self, now: float) -> list[tuple[str, ...]]:
        """The table's cells, one tuple per device (plain text, no markup)."""
        out = []
        for lg in self.loggers:
            st = lg.stats
            rates = self.rates(lg.spec.name)
            rate, byte_rate = ("-", "-") if rates is None else (f"{rates[0]:.1f}/s", si(rates[1], "B/s"))
            age = "-" if st.last_data_mono is None else f"{max(now - st.last_data_mono, 0.0):.1f} s ago"
            out.append((
                lg.spec.name, "up" if st.connected else "down", rate, byte_rate, str(st.records),
                str(lg.decoder.stats().get("errors", 0)), str(st.gaps), age,
            ))  # fmt: skip
        return out

    def table(self, elapsed: float, now: float):
        from rich.table import Table

        table = Table(title=f"arva-bench log  {elapsed:7.1f} s", expand=False)
        for col in COLUMNS:
            table.add_column(col, justify="left" if col in ("device", "link") else "right")
        for row in self.rows(now):
            link = "[green]up[/]" if row[1] == "up" else "[red]down[/]"
            table.add_row(row[0], link, *row[2:])
        return table

    def start(self):
        """A rich Live display on stderr; call :meth:`update` to refresh it, ``stop()`` on it at the end."""
        from rich.console import Console
        from rich.live import Live

        now = time.monotonic()
        self.sample(now)
        live = Live(self.table(0.0, now), console=Console(stderr=True), refresh_per_second=4, transient=True)
        live.start()
        return live

    def update(self, live, elapsed: float) -> None:
        now = time.monotonic()
        self.sample(now)
        live.update(self.table(elapsed, now))
