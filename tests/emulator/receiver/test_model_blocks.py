"""The batch model's blocking (issue 20): block size, layout and threads change nothing.

Blocks of a few pairs exercise partial blocks, both layouts (poses or transmitters along
the contiguous axis), sparse inner-zone pairs and the at-transmitter case; the result must
equal the default blocks' bit for bit, for both receiver classes, with noise and fields.
"""

import numpy as np
import pytest

import model_properties as props
from emulator.receiver import model


def scene(seed: int, n: int, m: int, moving: bool):
    rng = np.random.default_rng(seed)
    rx_p = rng.uniform(-30, 30, (n, 3))
    tx_p = rng.uniform(-30, 30, (n, m, 3) if moving else (m, 3))
    rx_p[: min(3, n)] = (tx_p[0, 0] if moving else tx_p[0]) + rng.uniform(-2, 2, (min(3, n), 3))  # inner zone
    if n > 4:
        rx_p[4] = tx_p[4, 0] if moving else tx_p[0]  # at the transmitter
    return rx_p, rng.normal(size=(n, 4)), tx_p, rng.normal(size=(m, 4))


def fields(meas):
    return [meas.d, meas.delta, meas.zone, meas.field]


@pytest.mark.parametrize("antennas", [2, 3])
@pytest.mark.parametrize("n,m,moving,noisy", [(50, 3, False, False), (3, 40, False, True), (33, 5, True, True), (1, 1, False, False)])
def test_blocks_and_threads_give_identical_results(monkeypatch, antennas, n, m, moving, noisy):
    rx_p, rx_q, tx_p, tx_q = scene(n * 100 + m, n, m, moving)
    noise = np.random.default_rng(7).uniform(-0.5, 0.5, (n, m, 3)) if noisy else None
    params = model.ModelParams(antennas=antennas)
    ref = model.measure(rx_p, rx_q, tx_p, tx_q, params, noise=noise, want_field=True)
    for chunk in (1, 7, 64):
        monkeypatch.setattr(model, "CHUNK_PAIRS", chunk)
        for threads in (1, 3):
            got = model.measure(rx_p, rx_q, tx_p, tx_q, params, noise=noise, want_field=True, threads=threads)
            for a, b in zip(fields(got), fields(ref)):
                assert np.array_equal(a, b) and a.dtype == b.dtype


def test_a_bad_quaternion_in_a_later_block_names_the_smallest_norm(monkeypatch):
    monkeypatch.setattr(model, "CHUNK_PAIRS", 4)
    props.assert_the_smallest_bad_norm_is_named(threads=2)
