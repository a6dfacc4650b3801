"""Properties of the receiver model's output (emulator.receiver.model.measure) that the
3-antenna and the 2-antenna tests check alike. Positions in metres, quaternions [w, x, y, z]
(body to scene frame), d in cm, delta in degrees (BRIEF 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from emulator.receiver.model import ZONE_INNER, ZONE_MID, ZONE_OUTER, ModelParams, measure
from firmware_proto.errors import PoseError


def assert_one_reading_in_range(m) -> None:
    """The measurement ``m`` of one pair (``measure(..., want_field=True)``) is what a
    receiver can show: a finite field, and (d, delta) within its zone's range (-1/-1
    outside r_outer, delta 0 inside r_inner)."""
    d, delta, zone = int(m.d[0, 0]), int(m.delta[0, 0]), int(m.zone[0, 0])
    assert np.all(np.isfinite(m.field))
    if zone == ZONE_OUTER:
        assert (d, delta) == (-1, -1)
    elif zone == ZONE_INNER:
        assert 0 <= d <= 300 and delta == 0
    else:
        assert zone == ZONE_MID and 300 <= d <= 5000 and -89 <= delta <= 89


def assert_d_monotone_along_a_ray(direction, rx_q, tx_q, params: ModelParams = ModelParams()) -> None:
    """Walking away from a transmitter at the origin along ``direction`` (400 steps from
    1 mm to 200 m), d never falls, and once out of range the receiver stays out."""
    norm = math.hypot(*direction)
    t = np.geomspace(1e-3, 200, 400)
    pts = np.outer(t, np.array(direction) / norm)
    m = measure(pts, np.tile(rx_q, (len(t), 1)), [(0.0, 0.0, 0.0)], [tx_q], params)
    d = m.d[:, 0]
    outer = m.zone[:, 0] == ZONE_OUTER
    if outer.any():
        first = int(np.argmax(outer))
        assert outer[first:].all(), "once out of range along a ray, always out of range"
        d = d[:first]
    assert np.all(np.diff(d) >= 0)


def assert_the_smallest_bad_norm_is_named(**kw) -> None:
    """20 receiver poses, two with quaternions below the 1e-09 norm floor (poses 13 and
    17): measure (``kw``: its options) names the smaller norm, whatever block it lies in."""
    q = np.tile([1.0, 0.0, 0.0, 0.0], (20, 1))
    q[13] = [1e-12, 0, 0, 0]
    q[17] = [1e-15, 0, 0, 0]
    with pytest.raises(PoseError, match=r"receiver.orientation: quaternion norm 1e-15 is below 1e-09"):
        measure(np.full((20, 3), 5.0), q, [[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0, 0.0]], **kw)
