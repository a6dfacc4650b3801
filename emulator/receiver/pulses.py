"""Transmitter pulses and signal overlap (BRIEF 3.1 ``pulses``, Appendix A).

Transmitters pulse (ETSI EN 300 718): a receiver updates a transmitter only when one of
its pulses has just ended, and loses the weaker (or both) of two pulses that overlap.
Times in seconds here (milliseconds in the scene). Pulse times are a pure function of
time and each transmitter's seeded stream (keyed by its id), so chunking epochs, adding a
transmitter or a second receiver changes no other timing. The timing model in full:
docs/emulator.md "pulses".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from firmware_proto.errors import InputError

from emulator.schema import is_number

#: ETSI EN 300 718 pulse period range, ms (1000 +- 300).
PERIOD_RANGE_MS = (700.0, 1300.0)
#: Shortest pulse, ms.
MIN_PULSE_MS = 70.0
#: Shortest gap between pulses, ms.
MIN_OFF_MS = 400.0
#: Largest clock error accepted, ppm (0.1 %; real crystals are within ~100 ppm, and the
#: standard's +-80 Hz at 457 kHz is 175 ppm).
MAX_DRIFT_PPM = 1000.0
OVERLAP_MODES = ("weaker", "both")
#: Spawn-key tag of this effect's random streams ("PULS"), distinct from every other effect.
_TAG = 0x50554C53


def _fmt(v) -> str:
    return f"{v:g}" if is_number(v) else repr(v)


@dataclass(frozen=True)
class PulseConfig:
    """Scene settings of the ``pulses`` effect (times in milliseconds).

    * ``period_ms`` ``(lo, hi)``: each transmitter's period is drawn uniformly in it;
      700 <= lo <= hi <= 1300 (ETSI). Default (700, 1300).
    * ``periods_ms``: per-transmitter period overrides by id, each in [700, 1300].
    * ``phases_ms``: per-transmitter phase overrides by id, >= 0: the start of one of
      its pulses; otherwise the phase is uniform in [0, period).
    * ``pulse_ms``: pulse length, >= 70, leaving >= 400 ms off in the shortest
      possible period (``period_ms[0]`` and every override). Default 100.
    * ``drift_ppm``: each transmitter's clock error is uniform in +-drift_ppm and
      scales its period (not the pulse length), 0 <= drift_ppm <= 1000. Default 0.
    * ``overlap``: ``"weaker"`` (the weaker of two overlapping pulses is lost; at equal
      strength the higher id) or ``"both"`` (both are lost). Default "weaker".
    """

    period_ms: tuple[float, float] = PERIOD_RANGE_MS
    periods_ms: Mapping[int, float] = field(default_factory=dict)
    phases_ms: Mapping[int, float] = field(default_factory=dict)
    pulse_ms: float = 100.0
    drift_ppm: float = 0.0
    overlap: str = "weaker"

    def __post_init__(self) -> None:
        lo_ok, hi_ok = PERIOD_RANGE_MS
        rng = tuple(self.period_ms) if isinstance(self.period_ms, (tuple, list)) else None
        if rng is None or len(rng) != 2 or not all(map(is_number, rng)) or not lo_ok <= rng[0] <= rng[1] <= hi_ok:
            raise InputError(f"pulses.period_ms: must be [lo, hi] with {lo_ok:g} <= lo <= hi <= {hi_ok:g}, "
                             f"got {self.period_ms!r}")
        object.__setattr__(self, "period_ms", (float(rng[0]), float(rng[1])))
        periods = self._id_map("periods_ms", self.periods_ms)
        for tx_id, p in periods.items():
            if not lo_ok <= p <= hi_ok:
                raise InputError(f"pulses.periods_ms.{tx_id}: must be in [{lo_ok:g}, {hi_ok:g}], got {p:g}")
        object.__setattr__(self, "periods_ms", MappingProxyType(periods))
        phases = self._id_map("phases_ms", self.phases_ms)
        for tx_id, ph in phases.items():
            if ph < 0:
                raise InputError(f"pulses.phases_ms.{tx_id}: must be >= 0, got {ph:g}")
        object.__setattr__(self, "phases_ms", MappingProxyType(phases))
        if not is_number(self.pulse_ms) or self.pulse_ms < MIN_PULSE_MS:
            raise InputError(f"pulses.pulse_ms: must be >= {MIN_PULSE_MS:g}, got {_fmt(self.pulse_ms)}")
        shortest = min([rng[0], *periods.values()])
        if shortest - self.pulse_ms < MIN_OFF_MS:
            raise InputError(f"pulses.pulse_ms: must leave >= {MIN_OFF_MS:g} ms off in the shortest period "
                             f"({shortest:g} ms), got {self.pulse_ms:g}")
        if not is_number(self.drift_ppm) or not 0 <= self.drift_ppm <= MAX_DRIFT_PPM:
            raise InputError(f"pulses.drift_ppm: must be in [0, {MAX_DRIFT_PPM:g}], got {_fmt(self.drift_ppm)}")
        if self.overlap not in OVERLAP_MODES:
            raise InputError(f'pulses.overlap: must be "weaker" or "both", got {self.overlap!r}')

    @staticmethod
    def _id_map(key: str, value) -> dict[int, float]:
        if not isinstance(value, Mapping):
            raise InputError(f"pulses.{key}: must be a table of id = milliseconds, got {value!r}")
        out = {}
        for k, v in value.items():
            try:
                tx_id = int(k)  # TOML table keys are strings
            except (TypeError, ValueError):
                raise InputError(f"pulses.{key}: keys must be transmitter ids, got {k!r}") from None
            if isinstance(k, bool) or tx_id < 0 or (isinstance(k, str) and not k.isdigit()):
                raise InputError(f"pulses.{key}: keys must be transmitter ids, got {k!r}")
            if not is_number(v):
                raise InputError(f"pulses.{key}.{tx_id}: must be a finite number, got {v!r}")
            out[tx_id] = float(v)
        return out


class PulseEffect:
    """Pulsing transmitters and overlap (BRIEF 3.1 ``pulses``).

    Cost per epoch: O(M^2 * pulses per window) element-wise operations (one or two
    pulses per transmitter in a 1 s window), vectorised over the epochs of a batch; no
    random draws after construction. Measured: ~1 us/epoch with 4 transmitters, ~20 us
    with 20 (4096-epoch batches); nothing for a single transmitter beyond two floors.

    ``periods_s``, ``phases_s`` (M,) are the drawn timings in seconds (drift included),
    ``pulse_s`` the pulse length. Counters: ``pulses_ended`` (pulses of present
    transmitters that ended in a window), ``pulses_hidden`` (of those, hidden by overlap).
    """

    def __init__(self, config: PulseConfig, tx_ids: ArrayLike, seed: int) -> None:
        ids = np.asarray(tx_ids, dtype=np.int64)
        if ids.ndim != 1:
            raise InputError(f"pulses: transmitter ids must be a 1-D array, got shape {ids.shape}")
        if ids.size and (ids.min() < 0 or np.unique(ids).size != ids.size):
            raise InputError("pulses: transmitter ids must be distinct and >= 0")
        self.config = config
        self.ids = ids
        self.pulse_s = config.pulse_ms / 1000.0
        lo, hi = config.period_ms
        self.periods_s, self.phases_s = np.empty((2, ids.size))
        for j, tx_id in enumerate(ids.tolist()):
            # Three draws for every transmitter, used or not, so an override of one
            # setting never shifts the others.
            u_period, u_drift, u_phase = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_TAG, tx_id))).random(3)
            nominal = config.periods_ms.get(tx_id, lo + (hi - lo) * u_period)
            period = nominal * (1.0 + config.drift_ppm * 1e-6 * (2.0 * u_drift - 1.0))
            self.periods_s[j] = period / 1000.0
            phase_ms = config.phases_ms.get(tx_id)
            self.phases_s[j] = (u_phase * period if phase_ms is None else phase_ms) / 1000.0
        self.pulses_ended = self.pulses_hidden = 0

    def stats(self) -> dict[str, int]:
        return {"pulses_ended": self.pulses_ended, "pulses_hidden": self.pulses_hidden}

    def reported(self, t_prev: ArrayLike, t_now: ArrayLike, strength: ArrayLike,
                 present: ArrayLike) -> NDArray[np.bool_]:
        """(N, M) mask: transmitter j is reported in the epoch with window (t_prev, t_now].

        Reported means present (received at that epoch) and at least one of its pulses
        ended in the window and was not hidden. A pulse is hidden when it overlaps a pulse
        of another transmitter present at the same epoch: with ``overlap="weaker"`` if
        that one is stronger (larger ``strength``; at equal strength, lower id), with
        ``"both"`` always. A pulse is judged with the presence and strengths of the epoch
        in which it ends. ``t_prev``, ``t_now`` (N,) in seconds, ``t_prev <= t_now``.
        """
        t_prev = np.asarray(t_prev, dtype=np.float64)
        t_now = np.asarray(t_now, dtype=np.float64)
        strength = np.asarray(strength, dtype=np.float64)
        present = np.asarray(present, dtype=bool)
        n, m = t_now.shape[0] if t_now.ndim == 1 else -1, self.ids.size
        if t_now.ndim != 1 or t_prev.shape != t_now.shape:
            raise InputError(f"pulses: t_prev and t_now must be (N,) arrays, got {t_prev.shape} and {t_now.shape}")
        if strength.shape != (n, m) or present.shape != (n, m):
            raise InputError(
                f"pulses: strength and present must be ({n}, {m}), got {strength.shape} and {present.shape}"
            )
        out = np.zeros((n, m), dtype=bool)
        if n == 0 or m == 0:
            return out
        period, phase, width = self.periods_s, self.phases_s, self.pulse_s
        # Index of the last pulse ended at or before t: floor((t - phase - W) / P). A
        # pulse is in a window iff c(t_prev) < index <= c(t_now), so consecutive windows
        # count every pulse exactly once whatever the batching.
        c_prev = np.floor((t_prev[:, None] - phase - width) / period)
        count = np.floor((t_now[:, None] - phase - width) / period) - c_prev
        heard = present & (count > 0)
        self.pulses_ended += int(count[heard].sum())
        if m == 1:
            return heard
        id_lower = self.ids[None, :] < self.ids[:, None]  # [j, i]: id_i < id_j
        for j in range(m):
            rows = np.flatnonzero(heard[:, j])
            if rows.size == 0:
                continue
            # Which other transmitters hide a pulse of j, at each of these epochs.
            threat = present[rows].copy()
            threat[:, j] = False
            if self.config.overlap == "weaker":
                s_i, s_j = strength[rows], strength[rows, j][:, None]
                threat &= (s_i > s_j) | ((s_i == s_j) & id_lower[j])
            cnt = count[rows, j]
            first = c_prev[rows, j] + 1.0
            shown = np.zeros(rows.size, dtype=bool)
            for k in range(int(cnt.max())):
                live = k < cnt
                start = phase[j] + (first + k) * period[j]
                hidden = _overlaps(start, width, phase, period) & threat
                hidden = hidden.any(axis=1) & live
                self.pulses_hidden += int(hidden.sum())
                shown |= live & ~hidden
            out[rows, j] = shown
        return out


def _overlaps(start: NDArray, width: float, phase: NDArray, period: NDArray) -> NDArray[np.bool_]:
    """(R, M): does the pulse [start, start + W] (R,) overlap a pulse of transmitter i?

    A pulse of i starting at s overlaps iff s < start + W and start < s + W, written
    symmetrically so that a overlaps b exactly when b overlaps a. The overlapping starts
    lie in an interval of length 2W < 2 P_i, so the two starts at or before start + W
    cover every case; a third on the other side guards the rounding of the floor.
    """
    a = start[:, None]
    end = a + width
    base = np.floor((end - phase) / period)
    hit = np.zeros(base.shape, dtype=bool)
    for dk in (-1.0, 0.0, 1.0):
        s = phase + (base + dk) * period
        hit |= (s < end) & (a < s + width)
    return hit
