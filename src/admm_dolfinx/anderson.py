"""Anderson acceleration of a fixed-point map z ↦ T(z), distributed over MPI ranks.

Type-II Anderson mixing with memory k: keep the last k differences of the residuals
f = T(z) − z and of the images T(z), find γ minimising ‖f − ΔF γ‖_W (a small k × k
least-squares problem whose inner products are summed over all ranks), and propose
z⁺ = T(z) − ΔG γ. The caller safeguards the proposal (accepts it only if it lowers the
fixed-point residual) and projects it onto the feasible set.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import numpy.typing as npt
from mpi4py import MPI

__all__ = ["AndersonMixer", "weighted_norm"]


def weighted_norm(
    x: npt.NDArray[np.float64], weights: npt.NDArray[np.float64], comm: MPI.Comm
) -> float:
    """The global weighted norm sqrt(Σ w_i x_i²) of a distributed array; collective."""
    return float(np.sqrt(comm.allreduce(float(x @ (weights * x)), op=MPI.SUM)))


class AndersonMixer:
    """Type-II Anderson acceleration in a weighted, distributed inner product.

    Args:
        memory: Number k of stored differences (≥ 1).
        weights: Local weights w of the inner product ⟨a, b⟩ = Σ w_i a_i b_i.
        comm: Communicator over which the vectors are distributed.
        regularization: Relative Tikhonov shift of the normal equations (keeps the
            k × k system solvable when the differences become nearly dependent).
    """

    def __init__(
        self,
        memory: int,
        weights: npt.NDArray[np.float64],
        comm: MPI.Comm,
        regularization: float = 1e-10,
    ):
        if memory < 1:
            raise ValueError(f"Anderson memory must be at least 1, got {memory}.")
        self.memory = int(memory)
        self.weights = np.asarray(weights, dtype=np.float64)
        self.comm = comm
        self.regularization = regularization
        self._dF: deque = deque(maxlen=self.memory)
        self._dG: deque = deque(maxlen=self.memory)
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the stored history."""
        self._dF.clear()
        self._dG.clear()
        self._last = None

    def update(
        self, z: npt.NDArray[np.float64], Tz: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64] | None:
        """Record the pair (z, T(z)) and return the Anderson proposal; collective.

        Args:
            z: The point at which T was evaluated (local part).
            Tz: Its image (local part).

        Returns:
            The extrapolated point, or None while there is no history yet.
        """
        f = Tz - z
        if self._last is not None:
            f_prev, g_prev = self._last
            self._dF.append(f - f_prev)
            self._dG.append(Tz - g_prev)
        self._last = (f, Tz.copy())
        if not self._dF:
            return None
        dF = np.array(self._dF)  # (k, n_local)
        wdF = dF * self.weights
        local = np.concatenate([(wdF @ dF.T).ravel(), wdF @ f])
        total = np.empty_like(local)
        self.comm.Allreduce(local, total, op=MPI.SUM)
        k = dF.shape[0]
        gram = total[: k * k].reshape(k, k)
        rhs = total[k * k :]
        shift = self.regularization * max(np.trace(gram) / k, np.finfo(float).tiny)
        try:
            gamma = np.linalg.solve(gram + shift * np.eye(k), rhs)
        except np.linalg.LinAlgError:
            self.reset()
            return None
        return Tz - np.array(self._dG).T @ gamma
