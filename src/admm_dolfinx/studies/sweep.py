"""Sampling the penalty: iterations as a function of r, and the sampled optimum r̄.

This is the paper's "standard numerical optimal penalty parameter": run ADMM for many
r (200 points uniformly in (0.1, 10)·E in the paper) and keep the r with the fewest
iterations. It is what Figures 2 and 5 plot. One :class:`~admm_dolfinx.ADMMSolver` is
reused for all samples, so the symbolic factorisation is computed once and each
sample costs one numeric factorisation plus its iterations.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from admm_dolfinx.admm.solver import ADMMConvergenceError, ADMMSolver
from admm_dolfinx.operators.condensed import condensed_factor_applies
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["PenaltySweep", "paper_penalty_grid", "sample_penalty"]


@dataclass
class PenaltySweep:
    """Iterations of ADMM against r.

    Attributes:
        r: The sampled penalties.
        iterations: Iterations at each r where the stopping test was met (also where
            the KKT check then failed, as the paper's test does at a poor r);
            ``max_iter + 1`` where it was not met.
        converged: Whether each sample converged (the test met and the KKT check too).
        time: Wall-clock seconds of the whole sweep.
    """

    r: npt.NDArray[np.float64]
    iterations: npt.NDArray[np.int64]
    converged: npt.NDArray[np.bool_]
    time: float

    @property
    def best_index(self) -> int:
        """Index of the sampled optimum (fewest iterations; the smallest r on ties)."""
        return int(np.argmin(self.iterations))

    @property
    def r_best(self) -> float:
        """The sampled optimum r̄."""
        return float(self.r[self.best_index])

    @property
    def iterations_best(self) -> int:
        """Iterations at r̄."""
        return int(self.iterations[self.best_index])


def paper_penalty_grid(E: float, num: int = 200, low: float = 0.1, high: float = 10.0):
    """The paper's grid: ``num`` points uniformly spaced in (low, high)·E.

    The open interval is sampled at the centres of ``num`` equal cells, so neither
    end point (where ADMM is slowest) is included.

    Args:
        E: Young's modulus (the scale of r).
        num: Number of samples.
        low: Lower end, in units of E.
        high: Upper end, in units of E.

    Returns:
        The penalties, ascending.

    Raises:
        ValueError: For E ≤ 0, ``num`` < 1 or not 0 < low < high.
    """
    if not (np.isfinite(E) and E > 0):
        raise ValueError(f"E must be a positive finite number, got {E!r}.")
    if isinstance(num, bool) or not isinstance(num, int | np.integer) or num < 1:
        raise ValueError(f"num must be an integer ≥ 1, got {num!r}.")
    if not (np.isfinite(high) and 0.0 < low < high):
        raise ValueError(f"The grid needs 0 < low < high (finite), got low={low!r}, high={high!r}.")
    edges = np.linspace(low * E, high * E, num + 1)
    return 0.5 * (edges[:-1] + edges[1:])


def sample_penalty(
    problem: ContactProblem,
    r_values: Sequence[float] | npt.ArrayLike,
    *,
    mode: str = "paper",
    rtol: float | None = None,
    max_iter: int = 1000,
    petsc_options: dict | None = None,
    progress: Callable[[int, int, float, int], None] | None = None,
    **solver_options,
) -> PenaltySweep:
    """Run ADMM at every r and record the iteration counts; collective.

    Args:
        problem: The contact problem.
        r_values: Penalties to sample.
        mode: ADMM mode; ``"paper"`` (the default) is the paper's algorithm and test.
        rtol: ADMM stopping tolerance (the mode's default if None).
        max_iter: ADMM iteration cap per sample.
        petsc_options: Options of the step-1 solver.
        progress: Called as ``progress(k, n, r, iterations)`` after each sample.
        **solver_options: More :class:`~admm_dolfinx.ADMMSolver` options (e.g.
            ``expert={"alpha": 1.6}``; ``polish`` is off unless given, so that the
            counts are those of the ADMM iteration at each r).

    Returns:
        The sweep.

    Raises:
        ValueError: If ``r_values`` is empty, not 1D, or holds a penalty that is not
            positive and finite (checked before any solve).
    """
    r_values = np.asarray(r_values, dtype=np.float64)
    if r_values.ndim != 1 or r_values.size == 0:
        raise ValueError(
            f"r_values must be a non-empty 1D sequence of penalties, got shape {r_values.shape}."
        )
    bad = r_values[~(np.isfinite(r_values) & (r_values > 0))]
    if bad.size:
        raise ValueError(
            f"Every penalty of the sweep must be positive and finite; got {bad[:5].tolist()}."
        )
    iterations = np.empty(r_values.size, dtype=np.int64)
    converged = np.zeros(r_values.size, dtype=bool)
    t0 = time.perf_counter()
    # one condensed factorisation serves every r where it can (2D or a small floating
    # 3D body, one process)
    serial = problem.comm.size == 1
    condensed = True if serial and condensed_factor_applies(problem, petsc_options) else None
    solver_options.setdefault("polish", False)
    expert = dict(solver_options.pop("expert", None) or {})
    if condensed is not None:  # the caller's own choice stands
        expert.setdefault("condensed", condensed)
    # a sweep samples poor penalties on purpose: their slow solves are its data, not
    # news (the counts are returned), so the solver's slow-convergence warning is muted
    with (
        _slow_convergence_muted(),
        ADMMSolver(
            problem,
            penalty=float(r_values[0]),
            expert=expert,
            mode=mode,
            rtol=rtol,
            max_iter=max_iter,
            petsc_options=petsc_options,
            **solver_options,
        ) as solver,
    ):
        for k, r in enumerate(r_values):
            solver.set_penalty(float(r))
            try:
                iterations[k] = solver.solve().iterations
                converged[k] = True
            except ADMMConvergenceError as error:
                # the test was met but the residuals were not (the paper's
                # relative-change test at a poor r): its count, not converged
                met = error.result.status == "inaccurate"
                iterations[k] = error.result.iterations if met else max_iter + 1
            if progress is not None:
                progress(k + 1, r_values.size, float(r), int(iterations[k]))
    return PenaltySweep(
        r=r_values, iterations=iterations, converged=converged, time=time.perf_counter() - t0
    )


class _MuteSlowConvergence(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not getattr(record, "slow_convergence", False)


@contextlib.contextmanager
def _slow_convergence_muted():
    """Drop the solver's slow-convergence warning (only that one) inside the block."""
    log, mute = logging.getLogger("admm_dolfinx.admm.solver"), _MuteSlowConvergence()
    log.addFilter(mute)
    try:
        yield
    finally:
        log.removeFilter(mute)
