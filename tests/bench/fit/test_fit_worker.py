"""The fit's worker process (bench/fit/worker.py): the same floats as evaluating here.

The pose-error fit hands half of each stencil's points to a second process. These tests
check that what comes back is bit for bit what this process computes, that a whole fit
gives identical estimates, standard errors and evaluation counts with and without it,
that a failing worker leaves the fit's result unchanged, and that the worker ends with
its input."""

from __future__ import annotations

import os
import re
import signal
from dataclasses import replace

import numpy as np
import pytest

import bench.fit.parallel as parallel_module
from bench.fit.eiv import model_rows
from bench.fit.estimate import fit_table
from bench.fit.result import EIV_FREE, FitOptions
from bench.fit.likelihood import Likelihood, Params
import bench.fit.worker as worker_module
from bench.fit.worker import Worker, WorkerError
from emulator.receiver.model import ModelParams
from fit_campaign import PoseError, emulate_campaign

TRUTH = ModelParams(kappa_eq=1.542, r_en=80.0)
TARGET_ERROR = PoseError(gps_h=1.0, gps_v=1.5, gps_tau=30.0, attitude_deg=2.0, attitude_tau=30.0)
AT = Params(kappa_eq=1.54, r_en=80.5, gps_sigma=1.0, attitude_sigma=0.035, pose_sigma=1e-4)


@pytest.fixture(scope="module")
def table():
    return emulate_campaign(60, TRUTH, seed=7, pose_error=TARGET_ERROR)


@pytest.fixture
def worker():
    w = Worker()
    yield w
    w.close()


def _points(p: Params, n: int = 5) -> list[Params]:
    return [
        replace(p, kappa_eq=p.kappa_eq * (1 + 1e-3 * i), r_en=p.r_en * (1 - 3e-3 * i),
                gps_sigma=p.gps_sigma * (1 + 0.1 * i), attitude_sigma=p.attitude_sigma * (1 - 0.1 * i))
        for i in range(-(n // 2), n - n // 2)
    ]  # fmt: skip


@pytest.mark.subprocess
@pytest.mark.parametrize("block", [0, 1000])
def test_worker_log_p_is_bit_for_bit_this_process(table, worker, block):
    rows = model_rows(table, AT)
    like = Likelihood(rows)
    like.choose_regimes(AT)
    like.block, like.threads = block, 2
    points = _points(AT)
    worker.start(like, points)
    theirs = worker.results(len(points))
    for p, out in zip(points, theirs):
        assert out.tobytes() == like.logp(p).tobytes()
    # new regimes: the likelihood is shipped again, and answers follow them
    like.choose_regimes(replace(AT, r_en=60.0))
    worker.start(like, points[:2])
    for p, out in zip(points[:2], worker.results(2)):
        assert out.tobytes() == like.logp(p).tobytes()
    assert worker.cpu() > 0.0


@pytest.mark.subprocess
def test_worker_reports_an_unknown_likelihood_and_goes_on(table, worker):
    like = Likelihood(model_rows(table, AT))
    like.choose_regimes(AT)
    worker._send(("eval", 999, [AT]))
    with pytest.raises(WorkerError, match="no likelihood 999"):
        worker.results(1)
    worker.start(like, [AT])
    assert worker.results(1)[0].tobytes() == like.logp(AT).tobytes()


@pytest.mark.subprocess
def test_worker_ends_with_its_input():
    w = Worker()
    w.close()
    assert w.proc.returncode == 0


@pytest.fixture(scope="module")
def small():
    """A 40-minute campaign (2400 rows; the worker takes likelihoods of >= 1000 rows
    here) and its fit with threads only."""
    t = emulate_campaign(40, TRUTH, seed=7, pose_error=TARGET_ERROR)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(parallel_module, "STENCIL_THREADS", 2)
        mp.setattr(parallel_module, "STENCIL_WORKER", False)
        return t, _fit(t)


def _fit(table):
    return fit_table(table, FitOptions(free=EIV_FREE))


@pytest.fixture
def with_worker(monkeypatch):
    monkeypatch.setattr(parallel_module, "WORKER_ROWS", 1000)
    monkeypatch.setattr(parallel_module, "STENCIL_THREADS", 2)
    monkeypatch.setattr(parallel_module, "STENCIL_WORKER", True)
    monkeypatch.setattr(parallel_module, "_worker_failed", False)
    return monkeypatch


@pytest.mark.slow
@pytest.mark.subprocess
def test_fit_with_the_worker_is_the_fit_without_it(small, with_worker):
    table, reference = small
    sent = []
    real = Worker.start
    with_worker.setattr(Worker, "start", lambda self, like, ps: (sent.append(len(ps)), real(self, like, ps))[1])
    fitted = _fit(table)
    assert sum(sent) > 50  # the worker did take stencil points
    assert fitted.converged and reference.converged
    assert fitted.estimate == reference.estimate
    assert fitted.se == reference.se
    assert fitted.log_likelihood == reference.log_likelihood
    assert (fitted.n_evals, fitted.n_evals_all_rows) == (reference.n_evals, reference.n_evals_all_rows)


@pytest.mark.subprocess
def test_a_failing_worker_leaves_the_fit_unchanged(small, with_worker):
    table, reference = small
    calls = []
    real = Worker.results

    def broken(self, n):
        calls.append(n)
        if len(calls) == 3:  # a few points in
            raise WorkerError("injected")
        return real(self, n)

    with_worker.setattr(Worker, "results", broken)
    failed = _fit(table)
    assert len(calls) == 3 and parallel_module._worker_failed and parallel_module._worker is None
    assert failed.estimate == reference.estimate and failed.se == reference.se
    assert failed.n_evals == reference.n_evals


def test_pose_moments_in_halves_are_the_whole(monkeypatch):
    """eiv_rows computes the pose moments of big tables in two halves on two threads."""
    from bench.fit.parallel import pose_moments_halves
    from bench.fit.pose_error import pose_moments, posterior_positions

    monkeypatch.setattr(parallel_module, "STENCIL_THREADS", 2)
    t = emulate_campaign(0, TRUTH, seed=3, n_rows=parallel_module.MOMENT_ROWS + 1, pose_error=TARGET_ERROR)
    pos = posterior_positions(t.rx_pos, t.tx_pos, 1.0, 1.5).pos
    rule = (1.0, 1.2, 0.035)
    whole = pose_moments(pos, t.rx_quat, t.tx_pos, t.tx_quat, rule)
    halves = pose_moments_halves(pos, t.rx_quat, t.tx_pos, t.tx_quat, rule)
    for name in ("m_xy", "v_xy", "m_3", "v_3", "dz_xy", "dz_3"):
        assert getattr(halves, name).tobytes() == getattr(whole, name).tobytes(), name
    assert halves.sigma0 == whole.sigma0
    quat = np.array(t.rx_quat, dtype=np.float64)
    quat[-3] = 1e-12  # a norm below the floor, in the second half
    with pytest.raises(Exception) as from_whole:
        pose_moments(pos, quat, t.tx_pos, t.tx_quat, rule)
    with pytest.raises(type(from_whole.value), match=re.escape(str(from_whole.value))):
        pose_moments_halves(pos, quat, t.tx_pos, t.tx_quat, rule)


_FORKED: list = []  # the likelihood a forked child finds (it cannot be pickled: a lock)


def _in_child():
    """(this process, the worker's owner, the worker's log P) in a forked child."""
    import os

    like = _FORKED[0]
    w = parallel_module.get_worker()
    w.start(like, [AT])
    return os.getpid(), w.owner, w.results(1)[0]


@pytest.mark.subprocess
def test_a_forked_child_starts_its_own_worker(table, with_worker):
    import multiprocessing
    import os

    like = Likelihood(model_rows(table, AT))
    like.choose_regimes(AT)
    mine = parallel_module.get_worker()
    mine.start(like, [AT])
    first = mine.results(1)[0]
    _FORKED[:] = [like]
    with multiprocessing.get_context("fork").Pool(1) as pool:
        pid, owner, theirs = pool.apply_async(_in_child).get(timeout=60)
    assert pid != os.getpid() and owner == pid
    assert theirs.tobytes() == first.tobytes() == like.logp(AT).tobytes()
    assert parallel_module.get_worker() is mine  # and this process's worker still answers
    mine.start(like, [AT])
    assert mine.results(1)[0].tobytes() == first.tobytes()


@pytest.mark.subprocess
@pytest.mark.timeout(120)  # without the answer timeout: a hang
def test_a_worker_that_stops_answering_is_killed_after_the_timeout(table, worker, monkeypatch):
    like = Likelihood(model_rows(table, AT))
    like.choose_regimes(AT)
    worker.start(like, [AT])
    assert worker.results(1)[0].tobytes() == like.logp(AT).tobytes()
    monkeypatch.setattr(worker_module, "ANSWER_TIMEOUT", 0.5)
    os.kill(worker.proc.pid, signal.SIGSTOP)  # hung: alive, never answers
    worker.start(like, [AT])
    with pytest.raises(WorkerError, match=r"^no answer within 0.5 s: the worker was killed$"):
        worker.results(1)
    assert worker.proc.wait(timeout=10) == -signal.SIGKILL


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(120)  # without the answer timeout: a hang
def test_a_hung_worker_leaves_the_fit_unchanged(small, with_worker):
    table, reference = small
    with_worker.setattr(worker_module, "ANSWER_TIMEOUT", 0.5)
    sent = []
    real = Worker.start

    def start_then_hang(self, like, ps):
        sent.append(len(ps))
        real(self, like, ps)
        if len(sent) == 3:  # a few points in, the worker stops answering
            os.kill(self.proc.pid, signal.SIGSTOP)

    with_worker.setattr(Worker, "start", start_then_hang)
    hung = _fit(table)
    assert len(sent) >= 3 and parallel_module._worker_failed and parallel_module._worker is None
    assert hung.estimate == reference.estimate and hung.se == reference.se
    assert hung.n_evals == reference.n_evals
