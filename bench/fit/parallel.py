"""Where the fit's likelihood evaluations run: stencil threads and the worker process.

The points of one finite-difference stencil are independent: :func:`evaluate` and
:func:`logps` evaluate them on up to :data:`STENCIL_THREADS` threads (numpy releases the
GIL), or, for errors-in-variables likelihoods of at least :data:`WORKER_ROWS` rows,
shared between a thread here and a worker process (:mod:`.worker`). Every evaluation is
the same floats wherever it runs, so only the time changes. Nothing here knows units.
"""

from __future__ import annotations

import atexit
import os
import pickle
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from .likelihood import Likelihood
from .pose_error import PoseMoments, pose_moments
from .worker import Worker, WorkerError


#: Likelihood evaluations at the points of one finite-difference stencil are independent,
#: and numpy releases the GIL inside its array loops: up to this many threads evaluate
#: them at once (each evaluation is unchanged, so the results are too).
STENCIL_THREADS = max(1, min(4, os.cpu_count() or 1))
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


#: Errors-in-variables likelihoods of at least this many rows evaluate a stencil's points
#: shared between a thread here and a worker process (:mod:`.worker`: the same floats;
#: two threads evaluated 10,000-row points only ~1.3x faster than one on two free cores).
#: False: threads only.
STENCIL_WORKER = True
WORKER_ROWS = 5000
_worker: Worker | None = None
_worker_failed = False


def stencil_pool() -> ThreadPoolExecutor:
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(STENCIL_THREADS, thread_name_prefix="fit-stencil")
    return _pool


def get_worker() -> Worker | None:
    """The worker process (started on first use), or None where it is not used."""
    global _worker, _worker_failed
    if not STENCIL_WORKER or STENCIL_THREADS == 1:
        return None
    with _pool_lock:
        if _worker_failed:
            return None
        if _worker is None or _worker.owner != os.getpid() or not _worker.alive():
            # (a forked child, e.g. a ProcessPoolExecutor's, must not share its parent's pipes)
            try:
                _worker = Worker()
            except (OSError, ValueError, TypeError):  # no interpreter to start (sys.executable)
                _worker_failed = True
                return None
            atexit.register(_worker.close)
        return _worker


def _drop_worker() -> None:
    """After a failure of the worker: evaluate in this process from now on."""
    global _worker, _worker_failed
    with _pool_lock:
        _worker_failed = True
        if _worker is not None and _worker.owner == os.getpid():
            _worker.proc.kill()
            _worker.proc.wait()
        _worker = None


def worker_cpu() -> float:
    """CPU time (s) the worker process has used so far (0 without one); for benchmarks."""
    w = _worker
    if w is None or w.owner != os.getpid() or not w.alive():
        return 0.0
    try:
        return w.cpu()
    except (OSError, EOFError, WorkerError, pickle.PickleError):
        return 0.0


def _worker_ok(like) -> bool:
    """Whether ``like``'s evaluations may go to the worker: an errors-in-variables
    :class:`Likelihood` (not a subclass) of at least :data:`WORKER_ROWS` rows, with its
    regimes chosen and no pose track (a time-offset fit)."""
    return (
        type(like) is Likelihood and like.rows.moments is not None and like.k.shape[0] >= WORKER_ROWS
        and like.regimes is not None and like.rows.track is None and STENCIL_THREADS > 1
    )  # fmt: skip


def evaluate(f, points: list) -> list[float]:
    """``[f(x) for x in points]``, on the stencil threads when there are several, or
    (:func:`_worker_ok`) shared with the worker process (:func:`_logps_split`)."""
    if STENCIL_THREADS == 1 or len(points) < 2:
        return [f(x) for x in points]
    like = getattr(f, "like", None)
    if like is not None and _worker_ok(like):
        done = _logps_split(like, [f.params(x) for x in points])
        if done is not None:
            return [-float(np.sum(out)) for out in done]  # like.nll's sum
    return list(stencil_pool().map(f, points))


def logps(like: Likelihood, params: list) -> list[NDArray[np.float64]]:
    """``[like.logp(p) for p in params]``, shared with the worker process when
    :func:`_worker_ok` (the same arrays either way)."""
    if len(params) >= 2 and _worker_ok(like):
        done = _logps_split(like, params)
        if done is not None:
            return done
    return [like.logp(p) for p in params]


def _logps_split(like: Likelihood, params: list) -> list[NDArray[np.float64]] | None:
    """``like.logp`` at ``params``, shared out between a stencil thread here (not the
    main thread: an evaluation of all rows stays in one piece) and the worker process, a
    point at a time from the front of one queue (whoever is free takes the next: with
    other jobs on the machine one of the two may be slowed). The worker's per-row log P
    are counted and kept as this process's own (:meth:`Likelihood.record`). Points
    ``like`` kept are not evaluated again. None when the worker is not available."""
    kept = [like.remembered(p) for p in params]  # (taken now: the batch's own results may push them out)
    todo = [i for i, out in enumerate(kept) if out is None]
    w = get_worker() if len(todo) >= 2 else None
    if w is None or not w.lock.acquire(blocking=False):
        return None
    queue = iter(todo)
    take = threading.Lock()
    theirs: dict[int, NDArray[np.float64]] = {}

    def nxt():
        with take:
            return next(queue, None)

    def local() -> dict[int, NDArray[np.float64]]:
        mine = {}
        while (i := nxt()) is not None:
            mine[i] = like.logp(params[i])
        return mine

    here = stencil_pool().submit(local)
    failed = False
    sent: list[int] = []
    try:
        # two points in flight, so the worker never waits for the round trip
        while len(sent) < 2 and (i := nxt()) is not None:
            w.start(like, [params[i]])
            sent.append(i)
        while sent:
            theirs[sent.pop(0)] = w.results(1)[0]
            if (i := nxt()) is not None:
                w.start(like, [params[i]])
                sent.append(i)
    except (OSError, EOFError, WorkerError, pickle.PickleError):
        failed = True
    finally:
        w.lock.release()
    mine = here.result()
    if failed:
        _drop_worker()
    for i, out in theirs.items():
        like.record(params[i], out)
        kept[i] = out
    for i, out in mine.items():
        kept[i] = out
    return [like.logp(p) if out is None else out for p, out in zip(params, kept)]  # (left by a failed worker)


#: Above this many rows :func:`pose_moments_halves` splits the table in two halves.
MOMENT_ROWS = 20_000


def pose_moments_halves(rx_pos, rx_quat, tx_pos, tx_quat, sigma0) -> PoseMoments:
    """:func:`pose_moments` of the two halves of the rows on the stencil threads: it is
    computed row by row, so the halves are the whole's values bit for bit (checked on the
    1e5-row bench campaign; ~0.15 s per call on one thread, three calls per fit). Should
    a half raise (a bad quaternion), the whole is computed again, which raises as before."""
    n = len(rx_pos)
    if STENCIL_THREADS == 1 or n < MOMENT_ROWS:
        return pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0)
    cols = [np.asarray(a) for a in (rx_pos, rx_quat, tx_pos, tx_quat)]
    halves = (slice(0, n // 2), slice(n // 2, n))
    try:
        parts = list(stencil_pool().map(lambda sl: pose_moments(*(c[sl] for c in cols), sigma0), halves))
    except Exception:  # noqa: BLE001 - the whole table's call below raises it (or not) as before
        return pose_moments(rx_pos, rx_quat, tx_pos, tx_quat, sigma0)
    a, b = parts
    return PoseMoments(
        *(np.concatenate([x, y], axis=1) for x, y in ((a.m_xy, b.m_xy), (a.v_xy, b.v_xy), (a.m_3, b.m_3), (a.v_3, b.v_3))),
        a.sigma0, np.concatenate([a.dz_xy, b.dz_xy]), np.concatenate([a.dz_3, b.dz_3]),
    )  # fmt: skip

