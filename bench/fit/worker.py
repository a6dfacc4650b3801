"""A second process that evaluates likelihoods for the fit (the points of a stencil).

The errors-in-variables likelihood is thousands of numpy calls of ~10 us each per
evaluation; two threads evaluating two stencil points hand the GIL over at every call,
which on the 2-core machine bought only ~1.3x over one thread (numpy's own loops, with
no GIL, ~1.7x). :class:`Worker` starts ``python -m bench.fit.worker`` once per
process, sends it a likelihood's rows and regimes once (per pass: when the regimes are
chosen again) and then batches of parameter points; it returns each point's per-row log
P, computed by the same code on the same arrays: the same floats as an evaluation in the
fit's own process (tests/bench/fit/test_fit_worker.py checks them bit for bit).

Protocol (pickle, over the child's stdin / stdout): ``("like", token, cls, rows,
regimes, block)`` keeps a likelihood (the last :data:`KEEP` shipped), ``("eval", token,
[Params])`` answers one ``("logp", array)`` per point in order, ``("cpu",)`` answers
``("cpu", seconds)`` (the worker's process time, for the benchmark). An exception in the
worker answers ``("error", text)``; the fit then evaluates locally. So does a worker
that has not answered within :data:`ANSWER_TIMEOUT` (it is killed: a hang never hangs
the fit). End of input ends the worker (so it never outlives the fit's process). Units: those of
:class:`.likelihood.Params`.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import time
import weakref
from collections import OrderedDict

from emulator.child_process import module_command, module_env

#: Likelihoods a worker keeps (the subsample's and all rows', with a spare).
KEEP = 4
#: glibc malloc settings for the worker (other C libraries ignore them): a fresh process
#: with a small heap gave the evaluation's freed temporaries back to the system after
#: each one and faulted them in again, 20-25 % more CPU per evaluation than the fit's
#: own (big-heap) process; with these it is the same (measured: 40 evaluations of 10,000
#: rows 0.76-0.81 s -> 0.61-0.64 s, the fit's process 0.65 s).
MALLOC_ENV = {"MALLOC_TRIM_THRESHOLD_": str(64 << 20), "MALLOC_MMAP_THRESHOLD_": str(32 << 20)}
#: Seconds the fit waits for one answer before it kills the worker and evaluates locally
#: (the same floats, only slower). One point of 1e5 rows takes ~0.06 s on the 2-core
#: machine of docs/performance.md, so only a hung or stopped worker reaches this; a
#: healthy one that did (a point of 1e8 rows under heavy load) costs speed, not results.
ANSWER_TIMEOUT = 120.0


class WorkerError(RuntimeError):
    """The worker process failed or answered out of turn."""


class Worker:
    """The parent's handle on one worker process (not thread-safe: one caller at a time)."""

    def __init__(self) -> None:
        env = module_env()
        for name, value in MALLOC_ENV.items():
            env.setdefault(name, value)
        self.proc = subprocess.Popen(
            module_command("bench.fit.worker"), stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
            start_new_session=True,  # a Ctrl-C at the terminal is the fit's to handle; the worker ends with its input
        )
        self.owner = os.getpid()  # the process whose pipes these are
        self.shipped: OrderedDict[int, object] = OrderedDict()  # token -> the regimes.exact it was shipped with
        self._next = 0
        self.lock = threading.Lock()

    def alive(self) -> bool:
        return self.proc.poll() is None

    def _send(self, msg) -> None:
        pickle.dump(msg, self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self.proc.stdin.flush()

    def _recv(self):
        timeout = ANSWER_TIMEOUT
        fired = threading.Event()

        def kill() -> None:
            fired.set()
            self.proc.kill()  # its end of the pipe closes: EOF here

        late = threading.Timer(timeout, kill)
        late.daemon = True
        late.start()
        try:
            msg = pickle.load(self.proc.stdout)
        except EOFError:
            if fired.is_set():
                raise WorkerError(f"no answer within {timeout:g} s: the worker was killed") from None
            raise
        finally:
            late.cancel()
        if msg[0] == "error":
            raise WorkerError(msg[1])
        return msg

    def token(self, like) -> int:
        """The worker's token for ``like`` at its current regimes, shipping it if needed."""
        exact = None if like.regimes is None else like.regimes.exact
        for tok, (ref, ex) in self.shipped.items():
            if ref() is like and ex is exact:
                return tok
        self._next += 1
        tok = self._next
        self._send(("like", tok, type(like), like.rows, like.regimes, like.block))
        self.shipped[tok] = (weakref.ref(like), exact)
        while len(self.shipped) > KEEP:
            self.shipped.popitem(last=False)
        return tok

    def start(self, like, params: list) -> None:
        """Send a batch; :meth:`results` collects it."""
        self._send(("eval", self.token(like), params))

    def results(self, n: int) -> list:
        return [self._recv()[1] for _ in range(n)]

    def cpu(self) -> float:
        """The worker's CPU time so far (s)."""
        with self.lock:
            self._send(("cpu",))
            return float(self._recv()[1])

    def close(self) -> None:
        """End the worker (its input closes; killed if it has not ended within 10 s).
        Nothing in a forked child, whose copies of the pipes are not its own."""
        if self.owner != os.getpid():
            return
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def main() -> int:
    """The worker's loop (``python -m bench.fit.worker``)."""
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing else may write to the protocol stream
    likes: OrderedDict = OrderedDict()
    while True:
        try:
            msg = pickle.load(inp)
        except EOFError:
            return 0
        try:
            if msg[0] == "like":  # no answer: a failure here answers the next "eval"
                likes[msg[1]] = None
                while len(likes) > KEEP:
                    likes.popitem(last=False)
                _tag, tok, cls, rows, regimes, block = msg
                like = cls(rows, regimes)
                like.block, like.threads = block, 1
                likes[tok] = like
                continue
            if msg[0] == "cpu":
                pickle.dump(("cpu", time.process_time()), out, protocol=pickle.HIGHEST_PROTOCOL)
                out.flush()
                continue
            _tag, tok, params = msg
            like = likes.get(tok)
            if like is None:
                raise WorkerError(f"no likelihood {tok}")
            for p in params:
                pickle.dump(("logp", like.logp(p)), out, protocol=pickle.HIGHEST_PROTOCOL)
                out.flush()
        except Exception as exc:  # noqa: BLE001 - reported to the parent, which evaluates locally
            if msg[0] == "like":
                continue  # (kept as None: the next "eval" of it answers the error)
            pickle.dump(("error", f"{type(exc).__name__}: {exc}"), out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (BrokenPipeError, ConnectionError):  # the fit's process went away mid-answer
        sys.exit(0)
