"""Starting values for the search: quick estimates from the rows themselves.

:func:`naive_fit` (least squares on detected mid-zone rows, what one would do by hand;
reported next to the fit), :func:`median_kappa` and :func:`pilot_sigma` (kappa_eq and the
relative pose error from near rows), and the grid helpers of the r_en pilot and the
time-offset scan (:func:`grid_values`, :func:`vertex_shift`). Distances in m, d in cm.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .params import BOUNDS
from .parallel import evaluate
from .rows import Rows


def naive_fit(rows: Rows, r_inner: float = 3.0) -> dict[str, float]:
    """Least squares on the detected mid-zone rows only (what one would do by hand).

    kappa: log-space least squares of d against the noise-free prediction,
    log kappa = mean(3 log(d/100) - 3 log r + log|g_xy|). r_en: least squares of the
    squared residuals against the small-noise variance eps^2/45, eps = 2 r^3/(r_en^3 |g_xy|).
    Both ignore censoring, rounding and the shape of the noise: biased near the range limit.
    """
    k = rows.k
    mid = k >= 100.0 * r_inner + 1
    if mid.sum() < 3:
        return {"kappa_eq": float("nan"), "r_en": float("nan")}
    log_r = rows.geo.log_r[mid]
    gx, gy, _ = rows.geo.g[:, mid]
    log_gxy = np.log(np.hypot(gx, gy))
    y = 3.0 * (np.log(k[mid] / 100.0) - log_r) + log_gxy  # = log kappa + 3 * noise term
    log_kappa = float(np.mean(y))
    res2 = ((y - log_kappa) / 3.0) ** 2
    w = 4.0 * np.exp(6.0 * log_r - 2.0 * log_gxy) / 45.0
    a = float(np.sum(w * res2) / np.sum(w * w))
    r_en = a ** (-1.0 / 6.0) if a > 0 else float("inf")
    return {"kappa_eq": math.exp(log_kappa), "r_en": r_en}


def median_kappa(rows: Rows, r_inner: float) -> float:
    """kappa_eq from the median of 3 log(d / dxy0) over mid-zone rows closer than 25 m."""
    k = rows.k
    mid = (k >= 100.0 * r_inner + 1) & (rows.geo.log_r < math.log(25.0))
    if mid.sum() < 3:
        mid = k >= 100.0 * r_inner + 1
    if mid.sum() < 1:
        return float("nan")
    gx, gy, _ = rows.geo.g[:, mid]
    y = 3.0 * (np.log(k[mid] / 100.0) - rows.geo.log_r[mid]) + np.log(np.hypot(gx, gy))
    return math.exp(float(np.median(y)))


def pilot_sigma(rows: Rows, kappa: float, r_inner: float) -> float:
    """The spread of log d on rows closer than 12 m (EMI negligible) beyond what the 1 cm
    rounding explains, from the median absolute deviation."""
    k = rows.k
    log_r = rows.geo.log_r
    gx, gy, gz = rows.geo.g
    near = (k > 0) & (log_r < math.log(12.0))
    if near.sum() < 10:
        return 1e-3
    mid = k > 100 * r_inner
    with np.errstate(divide="ignore"):
        gn = np.where(mid, np.hypot(gx, gy), np.sqrt(gx * gx + gy * gy + gz * gz))
        pred = log_r + (math.log(kappa) - np.log(gn)) / 3.0
    res = (np.log(np.maximum(k, 1) / 100.0) - pred)[near]
    res = res[np.isfinite(res)]
    if res.size < 10:
        return 1e-3
    mad = 1.4826 * float(np.median(np.abs(res - np.median(res))))
    rounding = float(np.median(1.0 / k[near])) / math.sqrt(12.0)
    return float(np.clip(math.sqrt(max(mad * mad - rounding * rounding, 0.0)), BOUNDS["pose_sigma"][0], 0.2))


def vertex_shift(values, i: int, step: float) -> float:
    """From grid point ``i`` (0 < i < len - 1) to the vertex of the parabola through it and
    its neighbours, for a grid of spacing ``step``: at most one step either way, and 0
    where the three values do not curve upwards."""
    vm, v0, vp = values[i - 1 : i + 2]
    curv = vp - 2.0 * v0 + vm
    if curv > 0:
        return float(np.clip(-0.5 * step * (vp - vm) / curv, -step, step))
    return 0.0


def grid_values(f, grid) -> tuple[NDArray[np.float64], int]:
    """f on the ``grid`` where the pilot needs it (NaN counts as +inf), and how many
    points that took: every other point, then the two neighbours of the best of those;
    +inf at the points not evaluated. Where f is unimodal on the grid (the likelihood in
    r_en is) its best point and that point's neighbours are among them: the same pilot
    as from every point, with 10 evaluations of 15."""
    values = np.full(len(grid), np.inf)
    coarse = list(range(0, len(grid), 2))
    values[coarse] = evaluate(f, [grid[i] for i in coarse])
    values = np.where(np.isnan(values), np.inf, values)
    best = coarse[int(np.argmin(values[coarse]))]
    fine = [i for i in (best - 1, best + 1) if 0 <= i < len(grid)]
    values[fine] = evaluate(f, [grid[i] for i in fine])
    return np.where(np.isnan(values), np.inf, values), len(coarse) + len(fine)

