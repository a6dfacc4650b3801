"""UTC time of day -> full UTC datetime, across midnight, from the last known date.

GGA and $PASHR carry only the time of day; RMC carries the date too. A
:class:`DayTracker` remembers the last full datetime (set by every RMC with a date, or
given at construction) and dates a bare time of day to whichever of the previous, same
or next day puts it closest to that datetime, then remembers the result. So a stream
crossing midnight -- including a GGA for 00:00:00 that arrives before the RMC carrying
the new date -- is dated correctly, as long as the stream never goes silent for 12 hours.

Until a date is known, times of day cannot be dated (``resolve`` returns None).
Dates are reported as the receiver sends them: no GPS week-rollover correction.
"""

from __future__ import annotations

from datetime import date, datetime, time, timedelta, timezone

_ONE_DAY = timedelta(days=1)


class DayTracker:
    """Dates times of day relative to the most recent full UTC datetime."""

    def __init__(self, start: datetime | None = None) -> None:
        if start is not None and start.tzinfo is None:
            start = start.replace(tzinfo=timezone.utc)
        self.latest: datetime | None = start

    def anchor(self, day: date, tod: time) -> datetime:
        """A full datetime from a sentence carrying both date and time (RMC)."""
        dt = datetime.combine(day, tod, tzinfo=timezone.utc)
        self.latest = dt
        return dt

    def resolve(self, tod: time | None) -> datetime | None:
        """``tod`` dated to the day that puts it nearest to the latest datetime (None
        without a ``tod`` or a date)."""
        latest = self.latest
        if tod is None or latest is None:
            return None
        base = datetime.combine(latest.date(), tod, tzinfo=timezone.utc)
        # Nearest wins; an exact 12-hour tie goes forward, as time does.
        best = min((base + _ONE_DAY, base, base - _ONE_DAY), key=lambda c: abs(c - latest))
        self.latest = best
        return best
