"""The receiver model of BRIEF section 3: (d, delta) and zones for N poses x M transmitters.

Units and frames as in :mod:`.types` (metres in the world ENU frame, ``d`` in centimetres,
``delta`` in degrees, the field in scene units); the transmitter dipole points along its +x.

Here: :func:`measure` (input checks, blocks, threads, which path) and :func:`measure_one`.
:mod:`.reference` is the formula of BRIEF 3 (the general path); :mod:`.fast` gives the
same integers for the common case (ideal 3-antenna receiver, static transmitters, no
field) and hands every pair it cannot decide safely to it; :mod:`.channels` selects the
channels, :mod:`.types` holds ModelParams, Measurement and the constants. ``KERNEL``
(ARVA_MODEL_KERNEL): "fast" (default) or "general", see docs/model.md "One fast path,
and the switch".
"""

from __future__ import annotations

import functools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from emulator.frames.rotation import unit_quaternion_components, x_axis_components
from emulator.receiver.model import fast, reference
from emulator.receiver.model.channels import Epochs, select_channels
from emulator.receiver.model.reference import round_half_away
from emulator.receiver.model.types import (
    ANTENNAS, MAX_DELTA_DEG, ZONE_INNER, ZONE_MID, ZONE_OUTER, Batch, Measurement, ModelParams,
)
from firmware_proto.errors import InputError, PoseError

__all__ = [  # the model's public names, several re-exported from its modules
    "ANTENNAS", "CHUNK_PAIRS", "Epochs", "KERNEL", "KERNELS", "MAX_DELTA_DEG",
    "Measurement", "ModelParams", "ZONE_INNER", "ZONE_MID", "ZONE_OUTER",
    "measure", "measure_one", "round_half_away", "select_channels",
]

#: Pairs are evaluated in blocks of about this many, reusing 12 float scratch buffers per
#: block (3 MB: about the L2 of the 2-core Xeon here); smaller blocks pay more per-call
#: overhead than they win in cache hits (tests/perf/bench_model.py, docs/performance.md).
CHUNK_PAIRS = 1 << 15
KERNELS = ("fast", "general")
#: Which path takes the pairs the fast path applies to (see the module docstring).
KERNEL = os.environ.get("ARVA_MODEL_KERNEL", "fast")


def measure(
    rx_position: ArrayLike, rx_orientation: ArrayLike, tx_position: ArrayLike, tx_orientation: ArrayLike,
    params: ModelParams = ModelParams(), noise: NDArray[np.float64] | None = None, want_field: bool = False,
    threads: int = 1,
) -> Measurement:
    """Evaluate N receiver poses against M transmitters.

    ``rx_position`` (N, 3) and ``rx_orientation`` (N, 4); ``tx_position`` (M, 3) or
    (N, M, 3) and ``tx_orientation`` (M, 4) or (N, M, 4) for moving transmitters.
    Quaternions need not be normalised. ``noise``, when given, is (N, M, 3) points of
    the unit ball in the world frame (see :mod:`emulator.receiver.noise`); they are scaled by
    ``params.w_en`` and mapped by Q R_r^T (BRIEF 3.2). ``noise=None`` is the ideal
    receiver and costs nothing extra. ``params.antennas`` selects the receiver class
    (3: BRIEF 3; 2: the horizontal field in every zone, see the reference module).
    ``threads`` > 1 splits the poses into that many contiguous ranges evaluated in
    parallel threads (same results; worth it only for large N on idle cores).
    """
    batch = _checked_batch(rx_position, rx_orientation, tx_position, tx_orientation, params, noise, want_field)
    if KERNEL not in KERNELS:  # the switch is checked on every call
        raise InputError(f"ARVA_MODEL_KERNEL: must be one of {', '.join(KERNELS)}, got {KERNEL!r}")
    use_fast = KERNEL == "fast" and fast.applies(batch)
    n, m = batch.d.shape
    if use_fast:
        # The fast path writes d and delta of the mid (and inner) pairs only: the rest are
        # -1, filled here in one pass over the whole (fresh) array rather than block by
        # block (in-process A/B on 1e6 poses x 4 tx: 1-3 ns/pair less; the first touch of
        # the fresh pages streams better in one pass).
        batch.d.fill(-1)
        batch.delta.fill(-1)
    if n and m:
        run = fast.FastPath(batch).run if use_fast else functools.partial(reference.measure_poses, batch)
        _in_threads(run, n, batch.rows, threads)
    return Measurement(batch.d, batch.delta, batch.zone, batch.field)


def _checked_batch(rx_position, rx_orientation, tx_position, tx_orientation, params, noise, want_field) -> Batch:
    """The inputs of ``measure`` checked (a PoseError names the first bad one) and shaped,
    with fresh (N, M) outputs."""
    rx_p = _positions(rx_position, "receiver.position")
    tx_p = _positions(tx_position, "transmitter.position")
    # Receiver matrices are built per block (in cache); the quaternions are checked here.
    rx_q = _quaternions(rx_orientation, "receiver.orientation")
    try:  # transmitter dipole axes, component-major: (3, M) or (3, N, M)
        tx_m = x_axis_components(unit_quaternion_components(tx_orientation, "transmitter.orientation"))
    except PoseError:
        unit_quaternion_components(rx_q, "receiver.orientation")  # a receiver error comes first
        raise
    n = rx_p.shape[0]
    m = tx_p.shape[-2]
    moving_tx = tx_p.ndim == 3 or tx_m.ndim == 3
    if moving_tx:
        tx_p = np.broadcast_to(tx_p, (n, m, 3))
        tx_m = np.broadcast_to(tx_m if tx_m.ndim == 3 else tx_m[:, None, :], (3, n, m))
    return Batch(
        params=params, rx_p=rx_p, rx_q=rx_q, tx_p=tx_p, tx_m=tx_m, moving_tx=moving_tx, noise=noise,
        d=np.empty((n, m), dtype=np.int64), delta=np.empty((n, m), dtype=np.int64),
        zone=np.empty((n, m), dtype=np.int8), field=np.empty((n, m, 3)) if want_field else None,
        rows=max(1, CHUNK_PAIRS // max(m, 1)), chunk=CHUNK_PAIRS,
    )


def _in_threads(run: Callable[[int, int], None], n: int, rows: int, threads: int) -> None:
    """run(first, last) over poses 0..n-1: at once, or in up to ``threads`` contiguous
    ranges of whole blocks in parallel (numpy releases the GIL inside its loops; the
    ranges write disjoint slices of the outputs)."""
    parts = max(1, min(int(threads), -(-n // rows)))
    if parts == 1:
        run(0, n)
        return
    step = -(-n // (parts * rows)) * rows
    with ThreadPoolExecutor(max_workers=parts) as pool:
        for job in [pool.submit(run, lo, min(n, lo + step)) for lo in range(0, n, step)]:
            job.result()  # re-raises a worker's error (e.g. a PoseError)


def _positions(p: ArrayLike, field_name: str) -> NDArray[np.float64]:
    """float64 positions (..., 3); non-finite values are a :class:`PoseError`."""
    p = np.asarray(p, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise PoseError(field_name, f"a position has 3 components [x, y, z], got shape {p.shape}")
    if not _all_finite(p):
        raise PoseError(field_name, "position has a non-finite component")
    return p


def _all_finite(a: NDArray[np.float64]) -> bool:
    """No NaN or infinity in ``a``: its sum is finite (one pass, no temporary), or every
    element is (the sum of finite values may overflow)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if math.isfinite(np.sum(a)):
            return True
    return bool(np.all(np.isfinite(a)))


def _quaternions(q: ArrayLike, field: str) -> NDArray[np.float64]:
    """float64 quaternions (N, 4) with shape and finiteness checked (norms: per block)."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,) or not _all_finite(q):
        unit_quaternion_components(q, field)  # raises the PoseError naming the field
    return q


def measure_one(
    rx_position: ArrayLike, rx_orientation: ArrayLike, tx_position: ArrayLike,
    tx_orientation: ArrayLike = (1.0, 0.0, 0.0, 0.0), params: ModelParams = ModelParams(),
) -> tuple[int, int]:
    """(d [cm], delta [deg]) of one receiver pose and one transmitter, ideal receiver.

    A thin wrapper over :func:`measure`, so both share one implementation.
    """
    rx_p, rx_q, tx_p, tx_q = (np.asarray(a, dtype=np.float64)[None]
                              for a in (rx_position, rx_orientation, tx_position, tx_orientation))
    meas = measure(rx_p, rx_q, tx_p, tx_q, params)
    return int(meas.d[0, 0]), int(meas.delta[0, 0])
