"""EMI noise (BRIEF 3.2): the one effect inside the receiver model itself."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


class NoiseEffect:
    """EMI noise (BRIEF 3.2): one point uniform in the unit ball per (epoch, transmitter),
    in the world frame; the model scales it by w_en and maps it by Q R_r^T. One
    ``standard_normal`` call per batch, so chunking never changes the stream (how:
    docs/model.md section 3).
    """

    def __init__(self, seed: int, stream: int = 0) -> None:
        # One independent stream per receiver, derived from the scene seed.
        self._rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))

    def draw(self, n_epochs: int, n_transmitters: int) -> NDArray[np.float64]:
        """(n_epochs, n_transmitters, 3) points uniform in the unit ball, epoch-major."""
        return ball_points(self.normals(n_epochs, n_transmitters))

    def normals(self, n_epochs: int, n_transmitters: int) -> NDArray[np.float64]:
        """The stream's next (n_epochs, n_transmitters, 5) standard normals, which
        :func:`ball_points` maps to what :meth:`draw` returns (a batch of closed-loop runs
        draws each run's normals, then maps them all at once)."""
        return self._rng.standard_normal((n_epochs, n_transmitters, 5))


def ball_points(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 5) normals -> (..., 3) points uniform in the unit ball (a zero 5-vector, the
    padding of a batch, maps to the origin). Element-wise: a point does not depend on the
    array it is part of."""
    norm = np.sqrt(np.einsum("...i,...i->...", z, z))[..., None]
    # A zero 5-vector has probability 0; guard anyway so no NaN can ever appear.
    return np.divide(z[..., :3], norm, out=np.zeros(z.shape[:-1] + (3,)), where=norm > 0)
