"""The batch loop gives the per-run closed loop's rows, bit for bit.

``BatchLoop`` (emulator/closed_loop/batch.py) steps many runs together; ``ClosedLoop`` is
the reference. Identical means: the same rows (integers, flags, and floats compared with
``==``), from each run's own seeded noise streams consumed in the same order.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from emulator.closed_loop.batch import BatchLoop, run_batch
from emulator.closed_loop.case_study import load_case
from emulator.closed_loop.loop import ClosedLoop
from emulator.closed_loop.sweep import SweepConfig, burial, run_chunk, sweep

#: 30 burials, 1-4 transmitters each (27 have several), EMI noise on. (50 before: the
#: per-run reference is ~0.2 s of CPU a run; 30 still mix located transmitters, misses and
#: runs that end early in every batch, 14 distinct end times or more per strategy.)
CONFIG = SweepConfig(n=30, seed=11, t_max=450.0, noise=True)


def exact(rows):
    """Rows as tuples; NaN as None so that == compares everything exactly."""
    return [tuple(None if isinstance(v, float) and math.isnan(v) else v for v in r.values()) for r in rows]


@pytest.mark.slow
@pytest.mark.timeout(900)  # ~6 s alone; the per-run reference is the slow part
@pytest.mark.parametrize("strategy", ["receiver_only", "flux_reverse", "flux"])
def test_batch_rows_equal_per_run_rows(strategy):
    assert sum(len(burial(CONFIG, i)) > 1 for i in range(CONFIG.n)) >= 21  # several transmitters (27 of 30)
    tasks = [(strategy, 1.0, 0.2, i) for i in range(CONFIG.n)]
    reference, _ = run_chunk(replace(CONFIG, engine="run"), tasks)
    batched, _ = run_chunk(CONFIG, tasks)
    assert exact(batched) == exact(reference)
    found = sum(r["found"] for r in reference)
    # The comparison covers located transmitters, misses and runs that end early.
    assert 0 < found < len(reference) or strategy != "flux"
    assert len({r["t_end_s"] for r in reference}) > 10


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_batch_equals_per_run_on_a_dem_with_range_noise():
    """The case-study scenes: a DEM terrain, 2 cm range noise, a 4 m take-off, no strips
    (waiting for a signal), different yaws and gains in one batch."""
    scenes = []
    for case in (1, 2, 3, 4):
        for k_c, yaw in ((0.2, 0.0), (0.4, 200.0), (0.1, 290.0)):
            for controller in ("flux", "receiver_only"):
                s = load_case(case, controller, k_c=k_c)
                tx = s.transmitters[0]
                a = math.radians(yaw)
                traj = replace(tx.trajectory, orientations=np.array([[math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)]]))
                scenes.append(replace(s, transmitters=(replace(tx, trajectory=traj),)))
    batch = run_batch(scenes, 240.0)
    contacts = 0
    for scene, b in zip(scenes, batch):
        ref = ClosedLoop(scene, record=False).run(240.0)
        assert (b.t_end, b.path_length, b.located, b.exhausted, b.ground_contacts) == (
            ref.t_end, ref.path_length, ref.located, ref.exhausted, ref.ground_contacts)
        contacts += ref.ground_contacts
    assert sum(bool(b.located) for b in batch) >= 12


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sweep_engines_give_the_same_rows():
    """Mixed batches: every strategy and two gains in one BatchLoop (24 runs, 60 rows:
    52 located, 14 ending at t_max)."""
    cfg = SweepConfig(n=4, seed=2, t_max=900.0, k_c=(0.1, 0.4), chunk=36)
    a = sweep(cfg, workers=1)
    b = sweep(replace(cfg, engine="run"), workers=1)
    assert exact(a.rows) == exact(b.rows) and a.scene_s == b.scene_s


def test_batch_refuses_what_it_does_not_batch():
    s = load_case(1)
    with pytest.raises(ValueError, match="the same rate_hz and control_rate_hz; use ClosedLoop"):
        BatchLoop([s, replace(s, rate_hz=2.0)])
    with pytest.raises(ValueError, match="a batch needs at least one scene"):
        BatchLoop([])


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_receiver_class_passes_through():
    """A 2-antenna receiver (ModelParams.antennas) in the batch: the same rows as per run,
    and not the 3-antenna rows."""
    cfg = replace(CONFIG, n=12, antennas=2)
    tasks = [("receiver_only", 1.0, 0.2, i) for i in range(cfg.n)]
    batched, _ = run_chunk(cfg, tasks)
    reference, _ = run_chunk(replace(cfg, engine="run"), tasks)
    assert exact(batched) == exact(reference)
    three, _ = run_chunk(replace(cfg, antennas=3), tasks)
    assert exact(three) != exact(batched)
