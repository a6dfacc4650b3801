"""An independent, deliberately plain transcription of BRIEF section 3 for one pair.

It follows the brief's formulas literally (h_t = s/(4 pi r^5) A(p), rotations as
matrices, d from |h|) in pure Python floats. It is not numerically hardened, so tests
use it only in well-conditioned ranges; the benchmark uses it as the per-sample loop.
"""

from __future__ import annotations

import math


def quat_matrix(q):
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def mat_vec(m, v):
    return [sum(m[i][j] * v[j] for j in range(3)) for i in range(3)]


def mat_t_vec(m, v):
    return [sum(m[j][i] * v[j] for j in range(3)) for i in range(3)]


def round_half_away(x):
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def field(rx_p, rx_q, tx_p, tx_q, s=1.0):
    """Receiver-frame field h (scene units), BRIEF 3 steps 1-3, no noise."""
    rt, rr = quat_matrix(tx_q), quat_matrix(rx_q)
    p = mat_t_vec(rt, [a - b for a, b in zip(rx_p, tx_p)])
    x, y, z = p
    r = math.sqrt(x * x + y * y + z * z)
    k = s / (4 * math.pi * r**5)
    ht = [k * (2 * x * x - y * y - z * z), k * 3 * x * y, k * 3 * x * z]
    return mat_t_vec(rr, mat_vec(rt, ht))


def measure(rx_p, rx_q, tx_p, tx_q=(1, 0, 0, 0), kappa_eq=1.542, s=1.0, r_inner=3.0, r_outer=50.0, antennas=3):
    """(d cm, delta deg) per BRIEF 3 steps 4-5; ``antennas=2``: dxy in every zone, with
    (h_x, h_y) = (0, 0) outer (docs/model.md, receiver classes)."""
    if list(rx_p) == list(tx_p):
        return 0, 0
    hx, hy, hz = field(rx_p, rx_q, tx_p, tx_q, s)
    hxy = math.sqrt(hx * hx + hy * hy)
    if antennas == 2:
        if hxy == 0:
            return -1, -1
        dxy = (kappa_eq / (4 * math.pi * hxy)) ** (1 / 3)
        if dxy <= r_inner:
            return round_half_away(100 * dxy), 0
    d3 = (kappa_eq / (4 * math.pi * math.sqrt(hx * hx + hy * hy + hz * hz))) ** (1 / 3)
    if antennas == 3 and d3 <= r_inner:
        return round_half_away(100 * d3), 0
    if hxy > 0:
        dxy = (kappa_eq / (4 * math.pi * hxy)) ** (1 / 3)
        if dxy <= r_outer:
            delta = math.copysign(90.0, hy) if hx == 0 else math.degrees(math.atan(hy / hx))
            return round_half_away(100 * dxy), max(-89, min(89, round_half_away(delta)))
    return -1, -1


def raw(rx_p, rx_q, tx_p, tx_q=(1, 0, 0, 0), kappa_eq=1.542, s=1.0):
    """Unrounded (d3 m, dxy m or inf, delta degrees or None) for boundary filtering."""
    hx, hy, hz = field(rx_p, rx_q, tx_p, tx_q, s)
    d3 = (kappa_eq / (4 * math.pi * math.sqrt(hx * hx + hy * hy + hz * hz))) ** (1 / 3)
    hxy = math.sqrt(hx * hx + hy * hy)
    if hxy == 0:
        return d3, math.inf, None
    dxy = (kappa_eq / (4 * math.pi * hxy)) ** (1 / 3)
    delta = math.copysign(90.0, hy) if hx == 0 else math.degrees(math.atan(hy / hx))
    return d3, dxy, delta


def delta_near_boundary(delta, eps=1e-6):
    """True if a raw delta (degrees) is a hair from where two correct float computations
    may round differently: a half degree, the +-89.5 clamp, or atan's +-90 fold (there a
    rounding residue of h_x decides the sign, e.g. -89.99999999999999 vs +89.99...)."""
    if delta is None:
        return False
    t = delta - 0.5 if delta >= 0 else delta + 0.5
    return abs(t - round(t)) < eps or abs(abs(delta) - 89.5) < eps or abs(abs(delta) - 90.0) < eps
