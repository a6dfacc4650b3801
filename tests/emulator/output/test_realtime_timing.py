"""Real-time epoch timing (issue 20): the first epoch is on time, and ``--timing-log``.

A fake clock advanced by sleeps and by rendering makes the timing exact and fast.
"""

import subprocess
import sys

import numpy as np
import pytest

from emulator.output.scheduler import EpochScheduler, Route


class FakeClock:
    """Each read takes 10 us (the scheduler spins on it before a deadline)."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        self.t += 1e-5
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


class SlowFirstRender:
    """A 20 Hz stream whose first render takes 30 ms of the fake clock (cold caches)."""

    rate_hz = 20.0

    def __init__(self, clock: FakeClock) -> None:
        self.clock = clock
        self.calls = 0

    def render(self, k: int, n: int) -> bytes:
        self.calls += 1
        self.clock.t += 0.030 if self.calls == 1 else 0.0001
        return b"%d\n" % k


class Sink:
    label = "arva"

    def __init__(self, clock: FakeClock) -> None:
        self.clock = clock
        self.writes = []

    def write(self, data: bytes) -> int:
        self.writes.append((self.clock(), data))
        return len(data)


def test_every_epoch_is_written_at_its_deadline_even_after_a_slow_first_render():
    clock = FakeClock()
    sink = Sink(clock)
    log = []
    sched = EpochScheduler([Route(SlowFirstRender(clock), sink)], speed=1.0, frames=6, clock=clock,
                           sleep=clock.sleep, on_write=lambda r, k, *t: log.append((k, *t)))
    sched.run()
    assert [d for _, d in sink.writes] == [b"%d\n" % k for k in range(6)]
    k, deadline, start, end = np.array(log).T
    assert k.tolist() == list(range(6))
    # Deadlines 50 ms apart from a start taken after the first (slow) render: the first
    # epoch is not late by the render time, and none is written before its deadline.
    assert np.allclose(np.diff(deadline), 0.05)
    assert np.all(start >= deadline) and np.all(start - deadline < 1e-3)
    assert np.all(end >= start)


@pytest.mark.subprocess
def test_timing_log_option_writes_one_line_per_epoch(tmp_path):
    log = tmp_path / "timing.csv"
    run = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--port", "-", "--frames", "5", "--speed", "20", "--timing-log", str(log)],
        capture_output=True, timeout=60,
    )
    assert run.returncode == 0, run.stderr
    lines = log.read_text().splitlines()
    assert lines[0] == "stream,epoch,deadline_s,write_start_s,write_end_s"
    rows = [line.split(",") for line in lines[1:]]
    assert [(r[0], int(r[1])) for r in rows] == [("arva", k) for k in range(5)]
    deadline, start, end = np.array([[float(v) for v in r[2:]] for r in rows]).T
    assert np.allclose(np.diff(deadline), 1.0 / 20.0)  # default scene 1 Hz at --speed 20
    assert np.all(start >= deadline) and np.all(end >= start)


@pytest.mark.subprocess
def test_timing_log_to_an_unwritable_path_is_an_input_error(tmp_path):
    bad = tmp_path / "missing" / "timing.csv"
    run = subprocess.run(
        [sys.executable, "-m", "emulator.cli", "--port", "-", "--frames", "2", "--speed", "20", "--timing-log", str(bad)],
        capture_output=True, timeout=60, text=True,
    )
    assert run.returncode == 2
    assert run.stdout == ""
    assert run.stderr == f"arva-emulate: --timing-log: cannot write {bad}: No such file or directory\n"
