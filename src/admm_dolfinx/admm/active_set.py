"""The primal-dual active-set walk of both polishers, remembered across attempts.

A polisher corrects a guessed contact set 𝒜 by primal-dual active-set steps: solve
the equality-constrained problem of 𝒜, let the nodes with λ < 0 leave and those that
penetrate join, and repeat until no node moves. The step taken from 𝒜 depends on 𝒜
alone (on the problem's data, not on the ADMM iterate that suggested the guess), so
every walk of a solve runs in one fixed graph of sets, and :class:`ActiveSetWalk`
computes each step of it once per solve:

* an attempt that reaches a set an earlier attempt stepped from follows the
  remembered steps at no cost, and goes on computing where that walk stopped;
* a walk stopped by its round limit is therefore *resumed* by the next attempt that
  joins it, not abandoned. The edge of the contact zone moves by a fraction of its
  error per round, so the rounds a walk needs grow with the number of contact nodes
  (``python benchmarks/scale_2d.py`` prints them); a limit per attempt must not
  become a limit per solve;
* a set whose walk ended (at a solution already proposed, at a singular system, or
  at a step that raised), or a walk that returns to a set it has visited (a cycle),
  gives nothing;
* a step computed from an inexact solve (the multigrid walk's coarse rounds) is a
  provisional one: the polisher forgets it after the walk (:meth:`ActiveSetWalk.forget`),
  so that no later walk follows it instead of the exact step. Such a step may also
  depend on the walk so far (the multigrid walk sheds more of a guess too large until
  it overshoots: :mod:`admm_dolfinx.admm.polish_sparse`); only the exact steps are the
  fixed graph's.

``python benchmarks/scale_2d.py`` shows the ADMM iteration counts this keeps flat as
the 2D mesh is refined.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

__all__ = ["ActiveSetWalk"]

Mask = npt.NDArray[np.bool_]
T = TypeVar("T")

#: ``step(𝒜) -> (solution, None)`` where no node moves, ``(None, 𝒜')`` for the next
#: set, ``(None, None)`` where the equality-constrained problem of 𝒜 has no solution.
Step = Callable[[Mask], tuple[T | None, Mask | None]]


class ActiveSetWalk(Generic[T]):
    """The steps between active sets computed so far in a solve.

    Args:
        key: The identity of a set (equal on every rank for a distributed set: a
            collective digest; the set's bytes where one rank walks).
    """

    def __init__(self, key: Callable[[Mask], bytes]):
        self._key = key
        #: key → (key, mask) of the next set, or None where the walk ended.
        self._next: dict[bytes, tuple[bytes, Mask] | None] = {}

    def clear(self) -> None:
        """Forget every step (a new load, gap or penalty)."""
        self._next.clear()

    def forget(self, sets: list[Mask]) -> None:
        """Forget the steps from these sets; collective where the key is.

        For steps that an inexact solve computed, which a later walk must compute again.
        """
        for active in sets:
            self._next.pop(self._key(active), None)

    def __len__(self) -> int:
        """The number of steps computed since :meth:`clear`."""
        return len(self._next)

    def walk(self, start: Mask, step: Step[T], max_rounds: int) -> tuple[T | None, int]:
        """Walk from ``start`` for at most ``max_rounds`` new steps.

        Args:
            start: The guessed active set.
            step: The correction of one set (the polisher's equality solve).
            max_rounds: New steps (calls of ``step``) allowed in this walk; the
                remembered steps it follows are free.

        Returns:
            The solution, if the walk reached a set from which no node moves and whose
            solution was not returned before, else None; and the number of new steps.
        """
        key, active = self._key(start), start
        visited: set[bytes] = set()
        rounds = 0
        while key not in visited:  # a revisited set: the walk cycles
            visited.add(key)
            if key in self._next:
                known = self._next[key]
                if known is None:  # ended before: nothing new from here
                    return None, rounds
                key, active = known
                continue
            if rounds == max_rounds:  # the next attempt that gets here resumes
                return None, rounds
            try:
                solution, moved = step(active)
            except BaseException:
                self._next[key] = None  # not retried in this solve
                raise
            rounds += 1
            if moved is None:
                self._next[key] = None
                return solution, rounds
            moved_key = self._key(moved)
            self._next[key] = (moved_key, moved)
            key, active = moved_key, moved
        return None, rounds
