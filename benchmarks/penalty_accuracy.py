"""How much the eigenvalue tolerance moves r*: estimate_penalty against a dense reference.

The reference is every eigenvalue of the contact pencil computed densely with
numpy/scipy (the paper's Algorithm 5 where the normals are axis-aligned, the rotated
pencil for the curved Hertz contact; ``tests/dense_reference.py``, shared with the
tests). For each mesh it prints r* by the dense method from the condensed
factorisation (2D meshes, the default there) and by the iterative method at the default
tolerance (1e-2) and at 1e-8, the relative errors of λ_min, λ_max and r*, the λ_max
method, the operator applications and the time. Serial (the dense reference is). Run:

    python benchmarks/penalty_accuracy.py

Writes out_benchmarks/penalty_accuracy.csv.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

import admm_dolfinx
from admm_dolfinx.scenes.library import example1, example2, example3

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dense_reference import algorithm5_eigenvalues, rotated_pencil_eigenvalues

CASES = [
    *[(f"example1 h=1/{n}", (lambda n=n: example1(h=1 / n)), True) for n in (8, 16, 32, 64)],
    *[(f"example3 level {k}", (lambda k=k: example3(level=k)), True) for k in (0, 1, 2)],
    *[(f"hertz level {k}", (lambda k=k: example2(level=k)), False) for k in (0, 1)],
]


def reference(problem, aligned):
    """(λ_min, λ_max) of the dense pencil, ignoring rigid motions (λ = ∞)."""
    ev = algorithm5_eigenvalues(problem) if aligned else rotated_pencil_eigenvalues(problem)
    ev = ev[np.isfinite(ev)]
    return ev[0], ev[-1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    if MPI.COMM_WORLD.size > 1:
        raise SystemExit("penalty_accuracy.py is serial: the dense reference is.")
    rows = []
    for name, build, aligned in CASES:
        problem = build().problem(contact_normal=MODEL)
        lmin, lmax = reference(problem, aligned)
        r_ref = 1.0 / np.sqrt(lmin * lmax)
        configs = [("dense", None)] if problem.gdim == 2 else []
        configs += [("local", 1e-2), ("factorised", 1e-8)]
        for method, tol in configs:
            options = {"method": method} if tol is None else {"method": method, "tol": tol}
            est = admm_dolfinx.estimate_penalty(problem, **options)
            rows.append(
                {
                    "mesh": name,
                    "m": problem.num_contact_nodes,
                    "method": method,
                    "tol": "-" if tol is None else f"{tol:g}",
                    "r* (dense)": f"{r_ref:.6g}",
                    "r*": f"{est.r:.6g}",
                    "err λ_min": f"{abs(est.lambda_min / lmin - 1):.1e}",
                    "err λ_max": f"{abs(est.lambda_max / lmax - 1):.1e}",
                    "err r*": f"{abs(est.r / r_ref - 1):.1e}",
                    "λ_max by": est.details.get("lambda_max_method", "-"),
                    "solves": est.solves,
                    "time [s]": f"{est.time:.3f}",
                }
            )
        problem.destroy()
    print_and_save(rows, Path(args.out) / "penalty_accuracy.csv")


if __name__ == "__main__":
    main()
