"""What active-set polishing costs and saves in 3D: polish=False against polish=True.

In 2D the solver polishes by default. In 3D polishing needs the dense Schur complement
S_C of A onto the contact *surface*, whose factorisation costs more than A + r*NᵀMN's;
the default polishes only a body that the contact alone holds (a floating one, below
the dense-work limit of :func:`admm_dolfinx.operators.condensed.condensed_factor_applies`).
Three scenes: Example 3 (``--scene example3``, held by its top face; the paper's
contact model), the Hertz sphere (``--scene hertz_sphere``, floating; the obstacle's
normal) and, held out from the sphere's tuning, the same quarter ball under a load
that makes its contact zone three times as wide (``--scene wide_sphere``: a = 1.2 =
R/6.7, levels 1-3, up to a few thousand contact nodes). For each mesh, in one run:

* ``polish=False``: r* by the iterative estimate, β and r of the surface metric
  (:mod:`admm_dolfinx.operators.surface_metric`), one factorisation of A + rNᵀ(M + βL_Γ)N,
  accelerated ADMM to the default tolerance (1e-6);
* ``polish=True``: one factorisation of A condensed onto Γ_C, which gives r* densely,
  the compliance G and every step-1 solve; ADMM with active-set polishing;
* the default (``ADMMSolver(problem)``): where S_C is not cheap, a floating body
  (the sphere from level 3) is polished from step 1's own factors, T read off them by
  MUMPS's selected inverse entries (``default: polish`` says which polishing ran);
  every polishing attempt first refines ADMM's guess of the contact set by ADMM on Γ_C
  alone (dense, with T; :mod:`admm_dolfinx.admm.polish_dense`);
* ``walk alone``: the default without that refinement (the active-set walk starts from
  ADMM's guess itself), what the default did before;
* a plain linear-elastic solve of A + rNᵀMN (factorisation + 1 solve, the first's r);
* on one process, the other exact route to the dense compliance: the C × C block of
  (A + r*NᵀMN)⁻¹ read off the plain factors by MUMPS's selected inverse entries,
  next to what the condensed factorisation costs beyond the plain one.

Time = r* + factorisation + set-up at r + iterations (assembly and the final KKT
check excluded), with the largest relative KKT residual of each result and the
relative difference of the two displacements. Under MPI ``polish=True`` factorises
twice, since PETSc solves with a Schur complement on one process only: A + r*NᵀMN for
the ADMM, and the condensed factorisation for r* and G (counted in r*). Each pair's
times vary by 10-20 % between runs here (``--repeat`` keeps the fastest of several).

    python benchmarks/polish_3d.py              # Example 3: levels 0-3, the 257k-dof mesh
    python benchmarks/polish_3d.py --scene hertz_sphere   # the Hertz sphere, levels 0-3
    python benchmarks/polish_3d.py --scene wide_sphere    # its wide contact zone, levels 1-3
    python benchmarks/polish_3d.py --quick      # levels 0-1
    python benchmarks/polish_3d.py --repeat 2   # best of two runs of each
    python benchmarks/polish_3d.py --only "level 3"   # both level-3 meshes

Writes out_benchmarks/polish_3d_<scene>.csv.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save
from timing import timed

from admm_dolfinx import ADMMSolver
from admm_dolfinx.admm import polish_dense
from admm_dolfinx.linalg.mumps_schur import inverse_block
from admm_dolfinx.operators.condensed import ContactSupport
from admm_dolfinx.operators.penalised import PenalisedOperator
from admm_dolfinx.scenes.library import example3, hertz_sphere

#: The held-out floating scene's contact radius (the Hertz sphere's is 0.4, R = 8).
WIDE_HALF_WIDTH = 1.2
#: Per scene: the builder, the contact model and the meshes. Example 3 in the paper's
#: contact model (along the body's normal): the book's tables of this script were
#: measured in it, and SNES VI's bounds apply to Example 3 only in it.
SCENES = {
    "example3": (
        example3,
        "body",
        [
            ("level 0", {"level": 0}),
            ("level 1", {"level": 1}),
            ("level 2", {"level": 2}),
            ("level 3", {"level": 3}),
            ("level 3, h0=0.24", {"level": 3, "h_bottom": 0.24, "h_top": 0.24}),
        ],
    ),
    "hertz_sphere": (
        hertz_sphere,
        "obstacle",
        [(f"level {level}", {"level": level}) for level in range(4)],
    ),
    "wide_sphere": (
        lambda comm, **kwargs: hertz_sphere(comm, half_width=WIDE_HALF_WIDTH, **kwargs),
        "obstacle",
        [(f"level {level}", {"level": level}) for level in range(1, 4)],
    ),
}
#: The two variants, each to its own end (polishing is exact).
VARIANTS = (
    ("no polish", {"polish": False}),
    ("polish", {"polish": True}),
    ("default", {}),
    ("walk alone", {}),
)


def contact_solve(problem, walk_alone=False, **options):
    """(seconds without assembly and KKT, result) of one solve with these options.

    ``walk_alone``: polishing without its refinement of the guess on Γ_C.
    """
    inner = polish_dense.INNER_MAX_ITERATIONS
    polish_dense.INNER_MAX_ITERATIONS = 0 if walk_alone else inner
    try:
        with ADMMSolver(problem, **options) as solver:
            result = solver.solve()
    finally:
        polish_dense.INNER_MAX_ITERATIONS = inner
    t = result.timings
    seconds = t["penalty"] + t["operator"] + t["factorization"] + t["iterations"]
    return MPI.COMM_WORLD.allreduce(seconds, op=MPI.MAX), result


def plain_solve(problem, r, inverse_entries=False):
    """Factorise A + rNᵀMN and solve once (the plain linear-elastic reference).

    Returns the seconds of the contact block by inverse entries (or None), which are
    not part of the plain solve: see :func:`contact_block_of_inverse`.
    """
    operator = PenalisedOperator(problem, "plain_")
    b, x = problem.A.createVecs()
    try:
        b.set(1.0)
        operator.set_penalty(r)
        operator.solve(b, x)
        if not inverse_entries:
            return None
        return contact_block_of_inverse(problem, operator, b, x)
    finally:
        for obj in (operator, b, x):
            obj.destroy()


def contact_block_of_inverse(problem, operator, b, x):
    """Seconds to read the C × C block of (A + rNᵀMN)⁻¹ off the plain factors.

    The other exact route to the dense compliance that polishing needs: MUMPS's
    selected entries of the inverse (:func:`admm_dolfinx.linalg.mumps_schur.inverse_block`,
    what the default's polishing from the step-1 factors uses), with the
    factorisation the ADMM already has. Checked against one solve; one process.
    """
    dofs = ContactSupport.build(problem).dofs
    t0 = time.perf_counter()
    block = inverse_block(operator.ksp.getPC().getFactorMatrix(), dofs)
    seconds = time.perf_counter() - t0
    column = dofs.size // 2
    b.set(0.0)
    b.setValue(dofs[column], 1.0)
    b.assemble()
    operator.solve(b, x)
    entries = block[:, column]
    error = np.abs(x.getArray()[dofs] - entries).max() / np.abs(entries).max()
    if error > 1e-10:
        raise RuntimeError(f"inverse entries differ from a solve by {error:.1e}")
    return seconds


def relative_difference(problem, u, v):
    """‖u − v‖ / ‖v‖ over the owned dofs of all ranks."""
    owned = problem.V.dofmap.index_map.size_local * problem.V.dofmap.index_map_bs
    local = np.array([np.sum((u[:owned] - v[:owned]) ** 2), np.sum(v[:owned] ** 2)])
    total = problem.comm.allreduce(local, op=MPI.SUM)
    return float(np.sqrt(total[0] / total[1]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="levels 0-1 only")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each; the fastest")
    parser.add_argument("--only", help="the meshes whose name contains this")
    parser.add_argument("--scene", choices=sorted(SCENES), default="example3")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    build, model, meshes = SCENES[args.scene]
    for name, kwargs in meshes[:2] if args.quick else meshes:
        if args.only and args.only not in name:
            continue
        problem = build(comm, **kwargs).problem(contact_normal=model)
        best = {}
        for _ in range(max(1, args.repeat)):
            for variant, options in VARIANTS:
                seconds, result = contact_solve(problem, variant == "walk alone", **options)
                if variant not in best or seconds < best[variant][0]:
                    best[variant] = (seconds, result)
        (t_def, default), (t_pol, polished) = best["no polish"], best["polish"]
        r = default.penalty
        t_plain = min(
            timed(lambda p=problem, r=r: plain_solve(p, r))[0] for _ in range(max(1, args.repeat))
        )
        t_inverse = plain_solve(problem, r, inverse_entries=True) if comm.size == 1 else None
        row = {
            "mesh": name,
            "dofs": problem.A.getSize()[0],
            "m": problem.num_contact_nodes,
            "plain [s]": f"{t_plain:.3g}",
        }
        t_auto, auto = best["default"]
        t_walk, walk = best["walk alone"]
        for label, seconds, result in (
            ("no polish", t_def, default),
            ("polish", t_pol, polished),
            ("default", t_auto, auto),
            ("walk alone", t_walk, walk),
        ):
            t = result.timings
            row |= {
                f"{label}: its": result.iterations,
                f"{label}: r* [s]": f"{t['penalty']:.3g}",
                f"{label}: factorisation [s]": f"{t['factorization']:.3g}",
                f"{label}: set-up + iterations [s]": f"{t['operator'] + t['iterations']:.3g}",
                f"{label}: total [s]": f"{seconds:.3g}",
                f"{label}: / plain": f"{seconds / t_plain:.2f}",
                f"{label}: KKT": f"{result.kkt.max():.1e}",
            }
        row["polish / no polish"] = f"{t_pol / t_def:.2f}"
        row["default: polish"] = auto.polish.kind if auto.polish is not None else "none"
        row["default / no polish"] = f"{t_auto / t_def:.2f}"
        extra = polished.timings["factorization"] - default.timings["factorization"]
        row["condensed − plain factorisation [s]"] = f"{extra:.3g}" if comm.size == 1 else "–"
        row["C × C of (A + r*K)⁻¹ by inverse entries [s]"] = (
            f"{t_inverse:.3g}" if t_inverse is not None else "–"
        )
        row["‖u_d − u_p‖/‖u_p‖"] = (
            f"{relative_difference(problem, default.u.x.array, polished.u.x.array):.1e}"
        )
        rows.append(row)
        if comm.rank == 0:
            print(f"{name}: no polish {t_def:.3g} s, polish {t_pol:.3g} s", flush=True)
        problem.destroy()
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / f"polish_3d_{args.scene}.csv")


if __name__ == "__main__":
    main()
