"""Shared timing of the benchmark scripts: interleaved rounds, slowest rank, best of each.

Imported by the scripts in this folder (``python benchmarks/<script>.py`` puts the
folder on ``sys.path``). Collective: every rank must call the same functions.
"""

from __future__ import annotations

import time

from mpi4py import MPI


def timed(fn):
    """(seconds, value) of one call, the slowest rank's time."""
    MPI.COMM_WORLD.Barrier()
    t0 = time.perf_counter()
    value = fn()
    return MPI.COMM_WORLD.allreduce(time.perf_counter() - t0, op=MPI.MAX), value


def best_of_rounds(repeat, functions, min_time=2.0):
    """Fastest time of each function, measured in interleaved rounds (one call of each
    per round): at least ``repeat`` rounds, and more while they took under
    ``min_time`` seconds in all. Interleaving keeps slow phases of a noisy machine
    from favouring one of them (a 0.1 s solve varied by 50 % between runs here)."""
    best = {name: (float("inf"), None) for name in functions}
    rounds, spent = 0, 0.0
    while rounds < repeat or spent < min_time:
        for name, fn in functions.items():
            seconds, value = timed(fn)
            spent += seconds
            if seconds < best[name][0]:
                best[name] = (seconds, value)
        rounds += 1
    return best
