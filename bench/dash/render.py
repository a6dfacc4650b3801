"""Text art of the dashboard, as plain functions of the data (no textual here).

Everything the widgets show is built by these functions, so the tests can check exact
strings and the snapshots stay deterministic: no clock, no terminal size beyond the
``width`` argument. :func:`dial` draws δ relative to the receiver's x axis (up): the body
frame is x forward, y left (BRIEF 2) and δ = atan(h_y / h_x), so **δ > 0 points left**.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

BARS = "▁▂▃▄▅▆▇█"
MISSING = "·"  # an epoch in which the channel was not received
DASH = "—"
#: Widths of the fixed channel-table columns; the sparkline takes the rest.
TABLE_FIXED = 39
INNER_CM = 300  # d <= 3 m with δ = 0 is the inner zone (BRIEF 3, step 5)


def sparkline(values: Sequence[int | None], width: int) -> str:
    """The last ``width`` values, one character each, right-aligned; ``None`` (not
    received) is a dot. Bars scale from the smallest to the largest value shown (a
    constant series is a flat middle bar)."""
    if width <= 0:
        return ""
    shown = list(values)[-width:]
    valid = [v for v in shown if v is not None]
    lo, hi = (min(valid), max(valid)) if valid else (0, 0)
    out = []
    for v in shown:
        if v is None:
            out.append(MISSING)
        elif hi == lo:
            out.append(BARS[3])
        else:
            out.append(BARS[int((v - lo) * (len(BARS) - 1) / (hi - lo) + 0.5)])
    return "".join(out).rjust(width)


def metres(cm: int | None) -> str:
    return DASH if cm is None or cm < 0 else f"{cm / 100:.2f}"


def zone(d: int, delta: int) -> str:
    """The zone a reported (d, δ) comes from: ``inner`` (d <= 3 m, δ = 0), ``mid``, or
    ``—`` for an empty slot (outer zone or nothing received)."""
    if d < 0:
        return DASH
    return "inner" if d <= INNER_CM and delta == 0 else "mid"


def table_header(width: int) -> str:
    head = f"{'id':>3} {'d m':>7} {'δ°':>4} {'zone':<5} {'true m':>7} {'err m':>6}  "
    return (head + "d(t)")[:width].ljust(width) if width > len(head) else head[:width]


def channel_rows(slots: Sequence[tuple[int, int, int] | None], true_m: dict[int, float],
                 history: dict[int, Sequence[int | None]], width: int) -> list[str]:
    """Header plus one row per slot of the latest epoch (``history`` and ``true_m`` keyed by
    transmitter id); a slot None never arrived intact."""
    rows = [table_header(width)]
    for slot in slots:
        tx, d, delta = (-1, -1, -1) if slot is None else slot
        spark = sparkline(history.get(tx, ()) if tx >= 0 else (), max(0, width - TABLE_FIXED))
        if slot is None:
            ident, d_text, dl, zn = "?", "lost", DASH, DASH
        elif tx < 0 or d < 0:
            ident, d_text, dl, zn = "-", DASH, DASH, DASH
        else:
            ident, d_text, dl, zn = str(tx), metres(d), str(delta), zone(d, delta)
        true = true_m.get(tx) if d >= 0 else None
        true_text, err_text = (DASH, DASH) if true is None else (f"{true:.2f}", f"{d / 100 - true:+.2f}")
        rows.append(f"{ident:>3} {d_text:>7} {dl:>4} {zn:<5} {true_text:>7} {err_text:>6}  {spark}"[:width])
    return rows


# -- the direction dial ------------------------------------------------------------------

ARC_SAMPLES = 2  # arc points per degree: enough for a continuous arc of dots


def _by_angle(delta: float, chars: str) -> str:
    """The character of ``chars`` (ahead, ahead-left, ahead-right, left, right) nearest
    the direction ``delta`` degrees (positive: to the left)."""
    a = abs(delta)
    i = 0 if a < 22.5 else 1 if a < 67.5 else 3
    return chars[i if i == 0 else i + (delta <= 0)]


def dial(delta: int | None, marks: Sequence[tuple[int, int]] = (), radius: int = 5, width: int = 26) -> list[str]:
    """A half dial ``radius + 2`` lines high: a legend line (``+90°`` left, ``0°`` up the
    receiver's x axis, ``-90°`` right), the arc, and the receiver ``▲`` at the centre of
    the bottom line. ``delta`` (degrees, [-90, 90]) is drawn as a ray from the receiver
    with an arrow head on the arc; ``None`` draws no ray. ``marks`` are ``(id, delta)`` of
    the other channels, written as their id (one digit, else ``•``) on the arc."""
    rx = 2 * radius  # a terminal cell is about twice as high as wide
    cx = width // 2
    rows = radius + 2  # legend + radius rows above the centre + the centre line
    cy = rows - 1
    grid = [[" "] * width for _ in range(rows)]

    def cell(col: float, row: float) -> tuple[int, int]:
        # Round half away from the centre (and absorb float noise), so the dial is symmetric.
        off = col - cx
        c = cx + int(math.copysign(math.floor(abs(off) + 0.5 + 1e-9), off))
        return c, math.floor(row + 0.5 + 1e-9)

    def put(col: float, row: float, ch: str) -> None:
        c, r = cell(col, row)
        if 0 <= r < rows and 0 <= c < width:
            grid[r][c] = ch

    def at(angle: float, frac: float = 1.0) -> tuple[float, float]:
        a = math.radians(angle)
        return cx - math.sin(a) * rx * frac, cy - math.cos(a) * radius * frac

    for i in range(-90 * ARC_SAMPLES, 90 * ARC_SAMPLES + 1):
        put(*at(i / ARC_SAMPLES), "·")
    for text, col in (("+90°", cx - rx - 1), ("0°", cx), ("-90°", cx + rx - 2)):
        for i, ch in enumerate(text):
            put(col + i, 0, ch)
    for tx, angle in marks:
        put(*at(max(-90, min(90, angle))), str(tx) if 0 <= tx <= 9 else "•")
    if delta is not None:
        angle = max(-90.0, min(90.0, float(delta)))
        head = cell(*at(angle))
        steps = 8 * radius
        for s in range(1, steps):
            c = cell(*at(angle, s / steps))
            if c != head and c != (cx, cy):
                put(*c, _by_angle(angle, "│╲╱──"))
        put(*at(angle), _by_angle(angle, "↑↖↗←→"))
    put(cx, cy, "▲")
    return ["".join(r).rstrip() for r in grid]


def dial_caption(slot: tuple[int, int, int] | None) -> str:
    """What the ray shows: ``tx 4  7.61 m  δ -62°``, or why there is none."""
    if slot is None:
        return "no epoch yet"
    tx, d, delta = slot
    if tx < 0 or d < 0:
        return "no signal"
    if zone(d, delta) == "inner":
        return f"tx {tx}  {metres(d)} m  inner: no δ"
    return f"tx {tx}  {metres(d)} m  δ {delta:+d}°" if delta else f"tx {tx}  {metres(d)} m  δ 0°"


# -- ground truth and links ----------------------------------------------------------------


def _fix_summary(fix: dict | None) -> str:
    if fix is None:
        return "waiting for a fix"
    if not fix.get("valid"):
        return "no fix"
    if fix.get("sentence") == "GGA":
        parts = [f"fix q{fix.get('quality')}"]
        if fix.get("sats") is not None:
            parts.append(f"{fix['sats']} sats")
        if fix.get("hdop") is not None:
            parts.append(f"hdop {fix['hdop']:.1f}")
        return ", ".join(parts)
    return "fix (RMC)"


TRUTH_HEAD = 13  # "rx1  surveyed"


def num(value: float, width: int, decimals: int) -> str:
    """``value`` in ``width`` characters, and never ``-0.00``."""
    text = f"{value:{width}.{decimals}f}"
    return f"{0.0:{width}.{decimals}f}" if float(text) == 0 else text


def truth_lines(poses: dict, roles: Sequence[str], width: int) -> list[str]:
    """Per role: where it is (ENU metres, or lat/lon/alt until an origin is known) and how
    we know it (gps, surveyed, scene); a GPS's fix quality; the attitude (heading, roll,
    pitch in degrees) when one is known."""
    if not roles:
        return ["no ground truth", "(--gps, --attitude, --tx-pose,", " or an arvaemu:// source)"]
    out: list[str] = []
    if any(poses[r].position is not None for r in roles):
        out.append(f"{'':<{TRUTH_HEAD}} {'E m':>7} {'N m':>7} {'U m':>6}"[:width])
    for role in roles:
        pose = poses[role]
        head = f"{role:<4} {pose.via or '—':<8}"
        if pose.position is not None:
            where = " ".join(num(v, w, 2) for v, w in zip(pose.position, (7, 7, 6)))
        elif pose.geodetic is not None:
            where = "{:.6f} {:.6f} {:.1f}".format(*pose.geodetic)
        else:
            where = DASH
        out.append(f"{head:<{TRUTH_HEAD}} {where}"[:width])
        if pose.via == "gps":
            out.append(f"     {_fix_summary(pose.fix)}"[:width])
        if pose.hpr is not None and not (pose.via in ("scene", "surveyed") and role.startswith("tx")):
            h, r, p = pose.hpr
            out.append(f" hdg {num(h, 5, 1)}  roll {num(r, 6, 1)}  pitch {num(p, 5, 1)}"[:width])
    return out


def compact(n: int | None, width: int) -> str:
    """A counter in ``width`` characters: 999, then 12k, 3M."""
    if n is None:
        return DASH
    text = str(n)
    for div, unit in ((1000, "k"), (1_000_000, "M"), (1_000_000_000, "G")):
        if len(text) <= width:
            break
        text = f"{n // div}{unit}"
    return text


def age_text(age: float | None) -> str:
    if age is None:
        return DASH
    if age < 10:
        return f"{age:.1f}s"
    if age < 1000:
        return f"{age:.0f}s"
    return f"{age / 60:.0f}m" if age < 60000 else ">1000m"


def link_label(device: str) -> str:
    return device.replace("attitude", "att")


LINK_HEADER = f"{'device':<8} {'link':<5} {'ep/s':>4} {'cks':>3} {'gap':>3} {'last':>5} {'drop':>5}"


def link_state(link, now: float, stale_after: float) -> str:
    """``up``, ``STALE``, ``down``, ``end`` or ``wait`` (connecting)."""
    if link.state == "ended":
        return "end"
    if link.state == "down":
        return "down"
    if link.stale(now, stale_after):
        return "STALE"
    return "up" if link.state == "up" else "wait"


def link_row(link, now: float, stale_after: float) -> tuple[str, str]:
    """(row, state word) of one link: records per second (epochs for a receiver),
    checksum errors, seq gaps, time since the last data, bytes dropped."""
    c = link.counters
    rate = link.rate(now, stale_after)
    rate_text = DASH if rate is None else (f"{rate:.1f}" if rate < 100 else compact(round(rate), 4))
    gaps = compact(c.seq_gaps, 3) if link.kind == "arva" else DASH
    state = link_state(link, now, stale_after)
    return (f"{link_label(link.device)[:8]:<8} {state:<5} {rate_text:>4} {compact(c.checksum_errors, 3):>3} "
            f"{gaps:>3} {age_text(link.age(now)):>5} {compact(c.dropped_bytes, 5):>5}"), state


def size_text(n: int) -> str:
    if n < 10_000:
        return f"{n} B"
    if n < 10_000_000:
        return f"{n / 1000:.0f} kB"
    return f"{n / 1_000_000:.0f} MB"


LINK_DETAIL_HEADER = f"{'device':<8} {'bytes':>8} {'reopen':>6} url"


def link_detail(link, width: int = 80) -> str:
    """Where a link reads from, how much it read, how often it was reopened. A URL too
    long for ``width`` keeps its end (``…/2026-01-15-a/arva.raw``)."""
    c = link.counters
    head = f"{link_label(link.device)[:8]:<8} {size_text(c.bytes):>8} {c.reconnects:>6} "
    url = link.url or DASH
    room = width - len(head)
    if len(url) > room > 1:
        url = "…" + url[len(url) - room + 1 :]
    return (head + url)[:width]
