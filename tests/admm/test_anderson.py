"""Anderson mixing against independent answers: a dense least-squares solve and GMRES's
finite termination on linear maps. Every test runs serially and under MPI."""

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx.admm.anderson import AndersonMixer

COMM = MPI.COMM_WORLD


def _split(n: int) -> slice:
    """This rank's contiguous share of n entries (some ranks may hold none)."""
    counts = [n // COMM.size + (r < n % COMM.size) for r in range(COMM.size)]
    start = sum(counts[: COMM.rank])
    return slice(start, start + counts[COMM.rank])


def _gather(local: np.ndarray) -> np.ndarray:
    return np.concatenate(COMM.allgather(local))


@pytest.mark.parametrize("memory", [1, 3, 8])
def test_coefficients_match_dense_least_squares(memory):
    """γ = argmin ‖f − ΔF γ‖_W equals numpy's lstsq on the gathered, weighted data."""
    rng = np.random.default_rng(7)  # the same global data on every rank
    n = 23
    own = _split(n)
    weights = rng.uniform(0.1, 2.0, n)
    mixer = AndersonMixer(memory, weights[own], COMM)
    points = [rng.standard_normal(n) for _ in range(memory + 2)]
    images = [rng.standard_normal(n) for _ in range(memory + 2)]
    for z, tz in zip(points[:-1], images[:-1], strict=True):
        mixer.update(z[own], tz[own])
    f = images[-1] - points[-1]
    f_prev = images[-2] - points[-2]
    mixer._dF.append(f[own] - f_prev[own])  # the difference update() would store
    mixer._dG.append(images[-1][own] - images[-2][own])
    gamma = mixer.coefficients(f[own])

    dF = np.column_stack([_gather(d) for d in mixer._dF])
    root = np.sqrt(weights)[:, None]
    expected = np.linalg.lstsq(dF * root, f * root[:, 0], rcond=None)[0]
    np.testing.assert_allclose(gamma, expected, rtol=1e-10, atol=1e-12)
    assert np.allclose(COMM.allgather(gamma), gamma, rtol=0, atol=0)  # same on all ranks


def _linear_map(n: int, seed: int = 3):
    """z ↦ G z + c with a nonsymmetric G of spectral radius 0.95, and its fixed point."""
    rng = np.random.default_rng(seed)
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    G = Q @ np.diag(np.linspace(-0.95, 0.95, n)) @ Q.T + 0.02 * rng.standard_normal((n, n))
    G *= 0.95 / max(abs(np.linalg.eigvals(G)))
    c = rng.standard_normal(n)
    return G, c, np.linalg.solve(np.eye(n) - G, c)


def _iterate(G, c, memory, steps):
    n = c.size
    own = _split(n)
    mixer = AndersonMixer(memory, np.ones(own.stop - own.start), COMM) if memory else None
    z = np.zeros(own.stop - own.start)
    for _ in range(steps):
        tz = (G @ _gather(z) + c)[own]
        proposal = mixer.update(z, tz) if mixer else None
        z = tz if proposal is None else proposal
    return _gather(z)


def test_full_memory_terminates_like_gmres():
    """On an affine map in R^n, Anderson with memory ≥ n is GMRES on I − G: exact after
    n + 1 steps (up to round-off), where the plain iteration has barely started."""
    n = 12
    G, c, fixed_point = _linear_map(n)
    accelerated = _iterate(G, c, memory=n, steps=n + 1)
    plain = _iterate(G, c, memory=0, steps=n + 1)
    scale = np.linalg.norm(fixed_point)
    assert np.linalg.norm(accelerated - fixed_point) <= 1e-9 * scale
    assert np.linalg.norm(plain - fixed_point) >= 1e-2 * scale


def test_long_memory_reaches_round_off():
    """With a long memory the differences become nearly dependent; the QR-based least
    squares still drives the error to round-off level."""
    n = 40
    G, c, fixed_point = _linear_map(n, seed=11)
    z = _iterate(G, c, memory=30, steps=120)
    assert np.linalg.norm(z - fixed_point) <= 1e-11 * np.linalg.norm(fixed_point)


def test_memory_must_be_positive():
    with pytest.raises(ValueError, match="at least 1"):
        AndersonMixer(0, np.ones(3), COMM)


def test_nan_in_history_resets_on_every_rank():
    """A NaN on one rank gives no proposal on any rank (no rank waits for another)."""
    n = 10
    own = _split(n)
    mixer = AndersonMixer(3, np.ones(own.stop - own.start), COMM)
    rng = np.random.default_rng(5)
    z0, t0, z1, t1 = (rng.standard_normal(n)[own] for _ in range(4))
    assert mixer.update(z0, t0) is None  # no history yet
    if COMM.rank == 0 and t1.size:
        t1[0] = np.nan
    assert mixer.update(z1, t1) is None
    assert not mixer._dF  # started afresh
