"""Anderson acceleration of a fixed-point map z ↦ T(z), distributed over MPI ranks.

Type-II Anderson mixing with memory k: keep the last k differences of the residuals
f = T(z) − z and of the images T(z), find γ minimising ‖f − ΔF γ‖_W, and propose
z⁺ = T(z) − ΔG γ. The caller safeguards the proposal (accepts it only if it lowers the
fixed-point residual) and projects it onto the feasible set.

The least-squares problem is solved through a QR factorisation of W^½ [ΔF | f], not
through the normal equations ΔFᵀWΔF γ = ΔFᵀW f, whose condition number is the square
of ΔF's: the differences become nearly dependent as the iteration converges, and with
a long memory the normal equations then lose the digits that the tail of the
iteration needs. Under MPI the QR is a tall-skinny QR: each rank factorises its rows,
the (k+1) × (k+1) triangles are gathered and factorised once more, identically on
every rank, so every rank takes the same γ.
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
        weights: Local weights w > 0 of the inner product ⟨a, b⟩ = Σ w_i a_i b_i.
        comm: Communicator over which the vectors are distributed.
        rcond: Directions of ΔF whose singular value is below ``rcond`` times the
            largest are left out of the least-squares solution (they carry no
            information once the differences become nearly dependent).
    """

    def __init__(
        self,
        memory: int,
        weights: npt.NDArray[np.float64],
        comm: MPI.Comm,
        rcond: float = 1e-10,
    ):
        if memory < 1:
            raise ValueError(f"Anderson memory must be at least 1, got {memory}.")
        self.memory = int(memory)
        self.weights = np.asarray(weights, dtype=np.float64)
        self.comm = comm
        self.rcond = rcond
        self._sqrt_weights = np.sqrt(self.weights)
        self._dF: deque = deque(maxlen=self.memory)
        self._dG: deque = deque(maxlen=self.memory)
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the stored history."""
        self._dF.clear()
        self._dG.clear()
        self._last = None

    def coefficients(self, f: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """γ minimising ‖f − ΔF γ‖_W over the stored differences; collective.

        Args:
            f: The current residual (local part).

        Returns:
            γ, the same on every rank.
        """
        k = len(self._dF)
        columns = np.column_stack([*self._dF, f]) * self._sqrt_weights[:, None]
        triangles = self.comm.allgather(np.linalg.qr(columns, mode="r"))
        R = np.linalg.qr(np.vstack(triangles), mode="r")
        if R.shape[0] < k + 1:  # fewer rows than columns in all (a tiny problem)
            R = np.vstack([R, np.zeros((k + 1 - R.shape[0], k + 1))])
        # ‖f − ΔF γ‖ = ‖R[:k, k] − R[:k, :k] γ‖ up to a constant
        return np.linalg.lstsq(R[:k, :k], R[:k, k], rcond=self.rcond)[0]

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
        try:
            gamma = self.coefficients(f)
        except np.linalg.LinAlgError:  # NaN in the history: start afresh
            gamma = np.full(len(self._dF), np.nan)
        if not np.all(np.isfinite(gamma)):
            self.reset()
            return None
        return Tz - np.array(self._dG).T @ gamma
